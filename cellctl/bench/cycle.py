"""``cellctl bench cycle``: supervisor overhead per viewpoint, end-to-end cycle time, cycles/hour.

Runs the real daemon (in this process) with the sim workers as child processes. Overhead per
viewpoint is the scanning step's wall time minus the time spent inside worker requests (move,
capture) divided by the viewpoints: what the supervisor itself adds (bookkeeping, logging,
image handling, bus encode/decode). Classification overlaps the next move and is not counted.
"""

from __future__ import annotations

import statistics
import sys
import time
from typing import Any

from cellctl.bench.options import BenchOptions


def bench_cycle(opts: BenchOptions) -> dict[str, Any]:
    """``opts.n`` measured cycles (default 3) after the plan-priming one."""
    from cellctl.bench.reliability.sim_cell import running_sim_cell
    from cellctl.errors import CellError

    n = opts.n or 3
    runs = []
    with running_sim_cell(opts, "bench-cycle", ["robot.settle_s=0"]) as run:
        cfg, plc = run.cfg, run.plc
        for i in range(n):
            plc.to_idle()
            t0 = time.perf_counter()
            res = plc.run_cycle(900)
            dt = time.perf_counter() - t0
            if res.outcome.value != "completed":
                raise CellError(f"cycle {i}: {res.outcome.value}: {res.reason}")
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
    per_vp = statistics.median(r["scan_s_per_viewpoint"] for r in runs)
    fixed = statistics.median(r["cycle_s"] - r["scan_s_per_viewpoint"] * r["viewpoints"] for r in runs)
    return {
        "config": {
            "settle_s": cfg.robot.settle_s,
            "speed_scale": cfg.robot.speed_scale,
            "camera": f"{cfg.camera.width}x{cfg.camera.height}",
            "seed_pct": cfg.planner.seed_pct,
            "whole_bin": cfg.planner.whole.enabled,  # the shipped default: every station, both surfaces
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
