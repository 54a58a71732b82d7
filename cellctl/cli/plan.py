"""``cellctl plan``: run the offline viewpoint planner on a catalog bin or any mesh.

Example::

    cellctl plan --bin case_study --base "0 -1.13 -0.33 90" --json --png plan.png

    cellctl plan --mesh other.ply --whole --json --png whole.png

``--base`` is the robot base pose in the bin frame: x, y, z (m) and yaw (deg) about +Z.
``--whole`` plans the whole bin instead (stations around it, both surfaces, config
``planner.whole``; no ``--base``): every station's plan goes into the cache and the whole
plan's record beside them. The plan is written into the plan cache (``planner.plans_dir``)
unless ``--out`` names a file. Exit code 3: the plan is empty (its ``reason`` says why).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, Any

from cellctl.cli import add_config_arguments, config_from_args
from cellctl.errors import PlanningError
from cellctl.surface import SURFACES

if TYPE_CHECKING:
    from cellctl.planning.plan import Plan

__all__ = ["plan_summary", "register", "run"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help="plan inspection viewpoints and their order for a bin")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--bin", dest="bin_type", help="bin type from the catalog")
    src.add_argument("--mesh", help="any triangle mesh file in metres, bin frame (origin: top opening, +Z up)")
    p.add_argument("--base", default=None, help='robot base pose in the bin frame: "X Y Z YAW_DEG" (m, deg)')
    p.add_argument(
        "--whole",
        action="store_true",
        help="whole bin: stations around it, external and internal surface (config planner.whole)",
    )
    p.add_argument("--surface", choices=SURFACES, default=None)
    p.add_argument("--seed-pct", type=float, default=None, help="p_SP: seeds as %% of the surface's faces")
    p.add_argument("--mode", choices=("fast", "paper"), default=None)
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--paper-budget", type=float, default=None, help="paper mode: RRT* seconds per query (default 1.0)")
    p.add_argument(
        "--paper-strict",
        action="store_true",
        help="paper mode: no RRTConnect fallback when RRT* finds nothing within its budget",
    )
    p.add_argument("--out", default=None, help="write the plan file here instead of the cache")
    p.add_argument("--png", default=None, help="draw the plan into this PNG")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    add_config_arguments(p)
    p.set_defaults(func=run)


def parse_base(text: str) -> tuple[float, float, float, float]:
    """``"X Y Z YAW_DEG"`` → floats; PlanningError naming the text otherwise."""
    parts = text.replace(",", " ").split()
    try:
        vals = [float(v) for v in parts]
    except ValueError:
        vals = []
    if len(vals) != 4:
        raise PlanningError(f'--base {text!r}: expected 4 numbers "X Y Z YAW_DEG" (m, m, m, deg)')
    return vals[0], vals[1], vals[2], vals[3]


def plan_summary(plan: Plan) -> dict[str, Any]:
    """The ``--json`` object: counts, area, times, tour cost (+ ids and the empty-plan reason).

    The sub-objects are the plan file's (:meth:`~cellctl.planning.plan.Plan.to_json`), so the
    summary and the file always agree.
    """
    body = plan.to_json()
    return {
        "plan_id": plan.plan_id,
        "bin_type": plan.bin_type,
        "surface": plan.surface,
        "mode": plan.mode,
        "seed_pct": plan.params.seed_pct,
        "counts": body["counts"],
        "stage_counts": body["stage_counts"],
        "area": body["area"],
        "times_s": body["times_s"],
        "tour_cost": plan.tour_cost,
        "coverage": plan.coverage,
        "reason": plan.reason,
    }


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from cellctl.geometry.camera import CameraModel
    from cellctl.planning.mesh import load_bin_mesh, load_catalog_mesh
    from cellctl.planning.pipeline import PlanParams, base_pose_from_xyz_yaw, make_plan
    from cellctl.planning.planfile import plan_path, write_plan
    from cellctl.planning.robot import RobotModel

    cfg = config_from_args(args)
    pc = cfg.planner
    if args.whole:
        if args.base is not None:
            raise PlanningError("--whole chooses its own base poses (stations); drop --base")
        return run_whole(args, cfg)
    if args.base is None:
        raise PlanningError('--base "X Y Z YAW_DEG" is required (or --whole)')
    x, y, z, yaw = parse_base(args.base)
    if args.bin_type:
        mesh = load_catalog_mesh(cfg.path(cfg.catalog), args.bin_type)
    else:
        mesh = load_bin_mesh(args.mesh)
    params = PlanParams(
        surface=args.surface or pc.surface,
        seed_pct=args.seed_pct if args.seed_pct is not None else pc.seed_pct,
        mode=args.mode or pc.mode,
        seed=args.seed if args.seed is not None else pc.seed,
        paper_budget_s=float(args.paper_budget) if args.paper_budget is not None else PlanParams.paper_budget_s,
        paper_fallback=not args.paper_strict,
        camera=CameraModel.from_config(cfg.camera),
    )
    plan = make_plan(
        mesh,
        base_pose_from_xyz_yaw(x, y, z, yaw),
        params,
        RobotModel.from_config(cfg),
        bin_type=args.bin_type,
        show_bars=True,
    )
    out = write_plan(plan, args.out) if args.out else write_plan(plan, plan_path(cfg.path(pc.plans_dir), plan))
    if args.png:
        from cellctl.planning.render import render_plan

        render_plan(plan, mesh, args.png)
    summary = plan_summary(plan)
    summary["plan_file"] = str(out)
    if args.json:
        print(json.dumps(summary, indent=2, default=lambda o: float(o) if isinstance(o, np.floating) else str(o)))
    else:
        c = plan.counts
        print(
            f"plan {plan.plan_id} → {out}: {len(plan.viewpoints)} viewpoints "
            f"(generated {c.generated}, filtered {c.filtered}, reachable {c.reachable}, "
            f"greedy {c.greedy}, optimal cover {c.optimal_cover}), coverage {100 * plan.coverage:.1f} %, "
            f"{plan.times_s.total:.1f} s"
        )
    return _exit_code(plan.reason)


def run_whole(args: argparse.Namespace, cfg: Any) -> int:
    """``cellctl plan --whole``: stations, both surfaces, the modelled cycle time."""
    from cellctl.geometry.camera import CameraModel
    from cellctl.geometry.catalog import load_catalog
    from cellctl.planning.mesh import load_bin_mesh, load_catalog_mesh
    from cellctl.planning.plan import PlanParams
    from cellctl.planning.robot import RobotModel
    from cellctl.planning.whole import WholeParams, plan_whole, write_whole

    pc = cfg.planner
    bin_type = None
    if args.bin_type:
        mesh = load_catalog_mesh(cfg.path(cfg.catalog), args.bin_type)
        bin_type = load_catalog(cfg.path(cfg.catalog), verify_meshes=False).get(args.bin_type)
    else:
        mesh = load_bin_mesh(args.mesh)
    if args.surface is not None:
        raise PlanningError("--whole plans both surfaces; drop --surface")
    plan_params = PlanParams(
        seed_pct=args.seed_pct if args.seed_pct is not None else pc.seed_pct,
        mode=args.mode or pc.mode,
        seed=args.seed if args.seed is not None else pc.seed,
        camera=CameraModel.from_config(cfg.camera),
    )
    if plan_params.mode != "fast":
        raise PlanningError("--whole plans in fast mode only (paper mode's RRT* budget per query × stations)")
    params = WholeParams.for_cell(cfg, plan_params)  # the arm's own speed and acceleration fractions
    from cellctl.geometry.robot_model import _quiet_stdout

    with _quiet_stdout():  # ur-analytic-ik's C++ warnings on fd 1 would corrupt --json
        plan = plan_whole(mesh, params, RobotModel.from_config(cfg), bin_type=bin_type)
    out = write_whole(plan, cfg.path(pc.plans_dir), args.out)
    if args.png:
        from cellctl.planning.whole_render import render_whole

        for path in render_whole(plan, mesh, args.png):
            print(f"cellctl plan: wrote {path}", file=sys.stderr)
    body = plan.to_json()
    body["plan_file"] = str(out)
    # a bin no plan sees enough of says so now, not as `incomplete` cycles later (cellctl.seen)
    from cellctl.seen import whole_plan_warning

    body["min_seen_fraction"] = dict(cfg.classifier.verdict.min_seen_fraction)
    body["seen_warning"] = whole_plan_warning(plan, body["min_seen_fraction"])
    if body["seen_warning"]:
        print(f"cellctl plan: warning: {body['seen_warning']}", file=sys.stderr)
    if args.json:
        print(json.dumps(body, indent=2))
    else:
        surf = ", ".join(
            f"{k} {100 * v.area_fraction:.1f} % ({100 * v.bound_fraction:.1f} % of bound, {v.viewpoints} viewpoints)"
            for k, v in plan.surfaces.items()
        )
        print(
            f"whole plan {plan.plan_id} → {out}: {len(plan.stations)} stations; {surf}; "
            f"modelled cycle {plan.cycle_time_s:.0f} s; planned in {plan.times_s['total']:.1f} s"
        )
    return _exit_code(plan.reason)


def _exit_code(reason: str | None) -> int:
    """3 for an empty plan (its reason on stderr), else 0."""
    if reason:
        print(f"cellctl plan: empty plan: {reason}", file=sys.stderr)
        return 3
    return 0
