"""The fuzz driver: the slowed cell it runs against, :func:`run_fuzz` and ``cellctl bench fuzz``."""

from __future__ import annotations

import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from cellctl.bench.options import BenchOptions
from cellctl.bench.reliability.fuzz.contract import FuzzTarget
from cellctl.bench.reliability.fuzz.generators import CommandFuzzer

__all__ = ["FUZZ_OVERRIDES", "bench_fuzz", "run_fuzz", "slow_sim_robot"]

FUZZ_OVERRIDES = [
    "supervisor.required_workers=[robot]",
    "robot.speed_scale=0.001",  # parking takes 4000 s: a started cycle rests in Execute.approaching
    "supervisor.timeouts.approach=3600",
    "supervisor.auto_reset=false",
]
"""Config the fuzzed cell runs with (see :func:`slow_sim_robot`)."""


@contextmanager
def slow_sim_robot(cfg: Any) -> Iterator[None]:
    """Run the sim robot worker (in a thread of this process) for the fuzzed cell.

    Raises:
        CellError: its liveliness token does not appear within 30 s.
    """
    from cellctl.workers.robot import run_worker

    stop = threading.Event()
    t = threading.Thread(target=run_worker, args=(cfg, "sim", stop), name="fuzz-robot", daemon=True)
    t.start()
    try:
        yield
    finally:
        stop.set()
        t.join(30)


def run_fuzz(
    cell: Any, n: int, seed: int, *, drive_every: int = 20, progress: Callable[[int, int], None] | None = None
) -> dict[str, Any]:
    """Send ``n`` seeded cases to ``cell`` (half by query, half by put) and return the counts.

    Every ``drive_every`` cases one allowed command moves the machine on (not counted as a case).
    """
    fuzzer = CommandFuzzer(seed, cell.cfg.supervisor.max_command_bytes)
    target = FuzzTarget(cell, seed=seed)
    t0 = time.perf_counter()
    try:
        for i, case in enumerate(fuzzer.cases(n)):
            if i % drive_every == 0:
                target.drive()
            target.send(case, "query" if fuzzer.rng.random() < 0.5 else "put")
            if progress is not None and ((i + 1) % 500 == 0 or i + 1 == n):
                progress(i + 1, n)
    finally:
        target.finish()
    dt = time.perf_counter() - t0
    out = target.stats.as_dict()
    out["seconds"] = round(dt, 2)
    out["cases_per_s"] = round(n / dt, 1) if dt > 0 else None
    return out


def bench_fuzz(opts: BenchOptions) -> dict[str, Any]:
    """``cellctl bench fuzz``: a real cell on a private loopback port, ``opts.n`` cases (default 10000)
    from ``opts.seed``."""
    from cellctl.app import build_cell
    from cellctl.bus.session import private_bus_overrides
    from cellctl.config import load_config, output_overrides

    n = opts.n or 10_000
    tmp = tempfile.mkdtemp(prefix="cellctl-bench-fuzz-")
    cfg = load_config(opts.config, [*opts.overrides, *private_bus_overrides(), *output_overrides(tmp), *FUZZ_OVERRIDES])
    try:
        # No identification: the cycle never gets past approaching (no vision imports needed).
        with build_cell(cfg, identification=(None, None)) as cell, slow_sim_robot(cfg):
            out = run_fuzz(
                cell, n, opts.seed, progress=lambda i, k: print(f"bench fuzz {i}/{k}", file=sys.stderr, flush=True)
            )
            out["cycles_opened"] = len(cell.index.all())
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    out["target"] = "cell/<id>/cmd: zenoh tcp loopback, daemon router in this process, client session; sim robot"
    out["max_command_bytes"] = cfg.supervisor.max_command_bytes
    return out
