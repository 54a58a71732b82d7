"""``cellctl bench bus``: command→Ack and command→Status latency against a real daemon process."""

from __future__ import annotations

import queue
import statistics
import subprocess
import sys
import tempfile
import time
from typing import Any

from cellctl.bench.options import BenchOptions
from cellctl.bus import keys
from cellctl.bus.codec import decode_as, encode
from cellctl.bus.session import open_session, private_bus_overrides
from cellctl.config import load_config, output_overrides
from cellctl.errors import ConfigError
from cellctl.messages import Ack, Command, CommandName, Status


def _pct(xs: list[float], p: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, int(round(p / 100 * (len(s) - 1))))]


def _summary(xs: list[float]) -> dict[str, float]:
    return {
        "p50_ms": round(_pct(xs, 50), 3),
        "p99_ms": round(_pct(xs, 99), 3),
        "mean_ms": round(statistics.fmean(xs), 3),
        "max_ms": round(max(xs), 3),
        "n": len(xs),
    }


def bench_bus(opts: BenchOptions) -> dict[str, Any]:
    """Spawn ``cellctl run`` on a free loopback port and drive Reset/Stop cycles by query and put.

    ``opts.n`` commands (default 300), alternating Reset and Stop, half by query, half by put.
    """
    n = opts.n or 300
    tmp = tempfile.mkdtemp(prefix="cellctl-bench-bus-")
    overrides = [*opts.overrides, *private_bus_overrides(), *output_overrides(tmp)]
    cfg = load_config(opts.config, overrides)
    cmd = [sys.executable, "-m", "cellctl", "run"]
    for ov in overrides:
        cmd += ["--set", ov]
    if opts.config:
        cmd += ["--config", opts.config]
    daemon = subprocess.Popen(cmd, stdin=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                session = open_session(cfg, "client")
                break
            except ConfigError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        with session as s:
            statuses: queue.Queue[tuple[float, Status]] = queue.Queue()
            acks: queue.Queue[tuple[float, Ack]] = queue.Queue()
            s.declare_subscriber(
                keys.status(cfg.cell_id),
                lambda x: statuses.put((time.perf_counter(), decode_as(Status, x.payload.to_bytes()))),
            )
            s.declare_subscriber(
                keys.cmd_ack(cfg.cell_id),
                lambda x: acks.put((time.perf_counter(), decode_as(Ack, x.payload.to_bytes()))),
            )
            deadline = time.monotonic() + 20
            while not list(s.get(keys.status(cfg.cell_id), timeout=1.0)):
                if time.monotonic() > deadline:
                    raise RuntimeError("daemon did not come up")
                time.sleep(0.1)
            ack_query: list[float] = []
            ack_put: list[float] = []
            status_lat: list[float] = []
            seq: list[tuple[CommandName, str]] = [("reset", "Idle"), ("stop", "Stopped")]
            # raw query and put on purpose, not PlcClient: this bench measures the transport's command→Ack time
            # with one long-lived cmd/ack subscription; PlcClient's put subscribes per call (what a CLI needs)
            for i in range(n):
                name, target = seq[i % 2]
                msg = Command(command=name, request_id=f"b{i}")
                while not statuses.empty():
                    statuses.get_nowait()
                t0 = time.perf_counter()
                if i % 4 < 2:
                    (r,) = list(s.get(keys.cmd(cfg.cell_id), payload=encode(msg), timeout=5))
                    t1 = time.perf_counter()
                    if r.ok is None or not decode_as(Ack, r.ok.payload.to_bytes()).accepted:
                        raise RuntimeError(f"{name} rejected")
                    ack_query.append((t1 - t0) * 1e3)
                else:
                    s.put(keys.cmd(cfg.cell_id), encode(msg))
                    while True:
                        t1, ack = acks.get(timeout=5)
                        if ack.request_id == msg.request_id:
                            break
                    ack_put.append((t1 - t0) * 1e3)
                first = None
                while True:
                    t2, st = statuses.get(timeout=5)
                    first = first or t2
                    if st.state == target:
                        break
                status_lat.append((first - t0) * 1e3)
                if (i + 1) % 50 == 0 or i + 1 == n:
                    print(f"bench bus {i + 1}/{n}", file=sys.stderr)
    finally:
        daemon.terminate()
        daemon.wait(10)
    return {
        "transport": f"zenoh tcp loopback, daemon in its own process (router), client mode; n={n}",
        "command_to_ack_query": _summary(ack_query),
        "command_to_ack_put": _summary(ack_put),
        "command_to_first_status": _summary(status_lat),
        "target_p99_ms": 5.0,
    }
