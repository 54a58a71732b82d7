"""The whole sim cell driven by a PLC client, with a primed plan cache (for benches).

The daemon runs in this process and the sim workers as its child processes, exactly as
``cellctl run --with-workers``; outputs (logs, index, plan cache) go to a fresh temp folder.
"""

from __future__ import annotations

import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cellctl.bench.options import BenchOptions
from cellctl.bus.plc_client import PlcClient
from cellctl.config import CellConfig, load_config, output_overrides
from cellctl.errors import CellError

__all__ = ["FAST_SIM", "SimCellRun", "running_sim_cell"]

FAST_SIM = [
    "robot.settle_s=0",
    "robot.speed_scale=1000",
    "robot.plan_timeout_s=1.0",
    "camera.width=640",
    "camera.height=360",
    "planner.whole.enabled=false",
]
"""Sim settings for benches about the controller, not motion time: zero settle, motions ×1000,
640×360 frames, 1 s RRTConnect budget, single-station cycles (one plan, a short cycle: a whole-bin
cycle is the shipped default, ``--set planner.whole.enabled=true`` brings it back)."""


@dataclass
class SimCellRun:
    cfg: CellConfig
    cell: Any  # cellctl.app.Cell
    plc: PlcClient
    out: Path
    overrides: list[str]


@contextmanager
def running_sim_cell(opts: BenchOptions, name: str, base: list[str]) -> Iterator[SimCellRun]:
    """Start the sim cell with ``base`` + ``opts.overrides``, wait for its workers, prime the plan cache.

    The first cycle on an empty plan cache ends ``replan_required``; this waits for that
    planning job, so measured cycles all find their plan.

    Raises:
        CellError: the workers do not come up, or planning fails.
    """
    from cellctl.app import build_cell

    out = Path(tempfile.mkdtemp(prefix=f"cellctl-{name}-"))
    overrides = [*base, *opts.overrides, *output_overrides(out)]
    cfg = load_config(opts.config, overrides)
    with build_cell(cfg, with_workers=True, config_file=opts.config, overrides=overrides) as cell:
        with PlcClient(cfg, name) as plc:
            roles = list(cfg.supervisor.spawn_workers)
            if not plc.wait_workers(roles, 300):
                raise CellError(f"workers did not come up in 300 s: {plc.last_status}")
            plc.to_idle()
            first = plc.run_cycle(900)
            if first.outcome.value == "replan_required" and first.planner_job_id:
                print(f"{name}: planning job {first.planner_job_id} …", file=sys.stderr)
                end = plc.wait_plan_job(first.planner_job_id, 900)
                if end is None or end.state != "done":
                    raise CellError(f"planning job {first.planner_job_id} did not finish: {end}")
            elif first.outcome.value in ("failed", "aborted"):
                raise CellError(f"first cycle {first.outcome.value}: {first.reason}")
            yield SimCellRun(cfg, cell, plc, out, overrides)
