"""``cellctl bench cycle``: supervisor overhead per viewpoint, end-to-end cycle time, cycles/hour.

Runs the real daemon (in this process) with the sim workers as child processes. Overhead per
viewpoint is the scanning step's wall time minus the time spent inside worker requests (move,
capture) divided by the viewpoints: what the supervisor itself adds (bookkeeping, logging,
image handling, bus encode/decode). Classification overlaps the next move and is not counted.
"""

from __future__ import annotations

import argparse
import queue
import statistics
import sys
import tempfile
import time
from typing import Any

from cellctl.config import load_config


def bench_cycle(args: argparse.Namespace) -> dict[str, Any]:
    from cellctl.app import build_cell
    from cellctl.bus import keys
    from cellctl.bus.codec import decode_as, encode
    from cellctl.bus.session import open_session
    from cellctl.messages import Ack, Command, CycleResult, PlanJobProgress, Status

    n = args.n or 3
    out = tempfile.mkdtemp(prefix="cellctl-bench-cycle-")
    overrides = [
        "robot.settle_s=0",
        *args.overrides,
        f"recording.dir={out}",
        f"recording.index={out}/cells.db",
        f"planner.plans_dir={out}/plans",
        "supervisor.required_workers=[robot,camera,classifier,planner]",
    ]
    cfg = load_config(args.config, overrides)
    c = cfg.cell_id
    with build_cell(cfg, with_workers=True, config_file=args.config, overrides=overrides) as cell:
        s = open_session(cfg, "client")
        statuses: queue.Queue[Status] = queue.Queue()
        results: queue.Queue[CycleResult] = queue.Queue()
        progress: queue.Queue[PlanJobProgress] = queue.Queue()
        s.declare_subscriber(keys.status(c), lambda x: statuses.put(decode_as(Status, x.payload.to_bytes())))
        s.declare_subscriber(keys.result(c), lambda x: results.put(decode_as(CycleResult, x.payload.to_bytes())))
        s.declare_subscriber(
            keys.planner_job_progress(c), lambda x: progress.put(decode_as(PlanJobProgress, x.payload.to_bytes()))
        )

        def cmd(name: str) -> Ack:
            (r,) = list(s.get(keys.cmd(c), payload=encode(Command(command=name)), timeout=10))
            return decode_as(Ack, r.ok.payload.to_bytes())

        def wait(pred, timeout: float) -> bool:  # noqa: ANN001
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline:
                try:
                    if pred(statuses.get(timeout=0.5)):
                        return True
                except queue.Empty:
                    pass
            return False

        if not wait(lambda st: all(st.workers.get(r) for r in ("robot", "camera", "classifier", "planner")), 240):
            raise RuntimeError(f"workers did not come up: {cell.supervisor.status.workers}")

        def cycle() -> tuple[CycleResult, float]:
            cmd("reset")
            wait(lambda st: st.state == "Idle", 30)
            t0 = time.perf_counter()
            if not cmd("start").accepted:
                raise RuntimeError("start refused")
            res = results.get(timeout=900)
            dt = time.perf_counter() - t0
            wait(lambda st: st.state in ("Complete", "Aborted"), 30)
            if res.outcome.value in ("failed", "aborted"):
                raise RuntimeError(f"cycle {res.outcome.value}: {res.reason}")
            return res, dt

        first, _ = cycle()
        if first.outcome.value == "replan_required":
            print(f"bench cycle: planning job {first.planner_job_id} …", file=sys.stderr)
            while True:
                p = progress.get(timeout=900)
                if p.job_id == first.planner_job_id and p.state in ("done", "failed"):
                    if p.state == "failed":
                        raise RuntimeError(f"planning failed: {p.message}")
                    break
        runs = []
        for i in range(n):
            res, dt = cycle()
            if res.outcome.value != "completed":
                raise RuntimeError(f"cycle {i}: {res.outcome.value}: {res.reason}")
            t = res.timing or {}
            nv = max(1, len(res.viewpoints))
            scan_wall = t.get("steps_s", {}).get("scanning", 0.0)
            scan_rpc = t.get("rpc_s", {}).get("scanning", 0.0)
            runs.append(
                {
                    "viewpoints": len(res.viewpoints),
                    "cycle_s": dt,
                    "overhead_ms_per_viewpoint": (scan_wall - scan_rpc) / nv * 1e3,
                    "scan_s_per_viewpoint": scan_wall / nv,
                    "steps_s": t.get("steps_s"),
                }
            )
            print(f"bench cycle {i + 1}/{n}: {len(res.viewpoints)} viewpoints in {dt:.1f} s", file=sys.stderr)
        s.close()
    per_vp = statistics.median(r["scan_s_per_viewpoint"] for r in runs)
    fixed = statistics.median(r["cycle_s"] - r["scan_s_per_viewpoint"] * r["viewpoints"] for r in runs)
    return {
        "config": {
            "settle_s": cfg.robot.settle_s,
            "speed_scale": cfg.robot.speed_scale,
            "camera": f"{cfg.camera.width}x{cfg.camera.height}",
            "seed_pct": cfg.planner.seed_pct,
        },
        "cycles": runs,
        "overhead_ms_per_viewpoint": {
            "median": round(statistics.median(r["overhead_ms_per_viewpoint"] for r in runs), 3),
            "max": round(max(r["overhead_ms_per_viewpoint"] for r in runs), 3),
        },
        "viewpoints_per_cycle": runs[0]["viewpoints"],
        "cycle_s_median": round(statistics.median(r["cycle_s"] for r in runs), 2),
        "cycle_s_30_viewpoints": round(fixed + 30 * per_vp, 2),
        "cycle_s_30_viewpoints_note": "measured fixed part + 30 × measured per-viewpoint scan time",
        "cycles_per_hour": round(3600 / statistics.median(r["cycle_s"] for r in runs), 1),
        "target_overhead_ms_per_viewpoint": 5.0,
    }
