"""``cellctl bench plan``: fast vs paper mode on the case-study bin, external surface."""

from __future__ import annotations

import sys
from typing import Any

from cellctl.bench_options import BenchOptions

__all__ = ["bench_plan"]

BENCH_BIN = "case_study"
BENCH_BASE = (0.0, -1.13, -0.33, 90.0)  # the sim's nominal parking pose (cellctl.sim.scene)


def bench_plan(opts: BenchOptions) -> dict[str, Any]:
    """Run fast p10, paper p10, fast p40; return their ``plan --json`` summaries and the speed-up.

    ``opts.n`` (optional) overrides the paper-mode RRT* budget in tenths of a second
    (default 10 = 1.0 s per query, the paper's set-up).
    """
    from cellctl.cli.plan import plan_summary
    from cellctl.planning.mesh import load_catalog_mesh
    from cellctl.planning.pipeline import PlanParams, base_pose_from_xyz_yaw, make_plan
    from cellctl.planning.robot import default_robot_model

    cfg = opts.load_config()
    mesh = load_catalog_mesh(cfg.path(cfg.catalog), BENCH_BIN)
    T = base_pose_from_xyz_yaw(*BENCH_BASE)
    robot = default_robot_model()
    budget = (opts.n or 10) / 10.0
    out: dict[str, Any] = {"bin": BENCH_BIN, "base_xyz_yaw_deg": list(BENCH_BASE), "paper_budget_s": budget}
    for key, pct, mode in (("fast_p10", 10, "fast"), ("paper_p10", 10, "paper"), ("fast_p40", 40, "fast")):
        print(f"bench plan: {key}", file=sys.stderr)
        params = PlanParams(surface="external", seed_pct=pct, mode=mode, seed=opts.seed, paper_budget_s=budget)
        plan = make_plan(mesh, T, params, robot, bin_type=BENCH_BIN, show_bars=True)
        out[key] = plan_summary(plan)
    f, p = out["fast_p10"], out["paper_p10"]
    out["speedup_p10"] = p["times_s"]["total"] / max(f["times_s"]["total"], 1e-9)
    a_f, a_p = f["area"]["visible_selected_m2"], p["area"]["visible_selected_m2"]
    out["selected_area_diff_pct_p10"] = 100.0 * (a_f - a_p) / a_p if a_p > 0 else None
    return out
