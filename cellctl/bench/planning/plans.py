"""``cellctl bench plan``: fast vs paper mode on the case-study bin, external surface;
``cellctl bench whole-bin``: whole-bin plans of every catalog bin and a foreign mesh over seeds."""

from __future__ import annotations

import sys
from typing import Any

from cellctl.bench.options import BenchOptions
from cellctl.bench.planning.rows import PROCESSES, machine_info, median_worst, whole_row

__all__ = ["FOREIGN", "bench_plan", "bench_whole_bin", "foreign_mesh"]

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


# --- whole bin (issue 19) -------------------------------------------------------------------

WHOLE_SEEDS = 10
"""Seeds per bin (``--n`` overrides): every figure is reported as median and worst over them."""
FOREIGN = ("foreign_long", "foreign_basin")
"""Generated meshes not designed like the catalog's (:func:`foreign_mesh`), benched beside it."""


def foreign_mesh(name: str = "foreign_long") -> Any:
    """A bin the catalog does not have (no board: identification comes from the cycle's first station).

    ``foreign_long``: long and narrow (0.5 × 1.1 m), a bulge, an inset opening, two skids.
    ``foreign_basin``: wide and low, round (0.84 m across, 0.7 m high), its body bulging below a
    narrow neck (opening 0.44 m across) and tapering to a small bottom, on three legs.
    Other proportions and features than the three catalog bins, to check the planner is not
    tuned to them.

    Raises:
        PlanningError: an unknown name.
    """
    from cellctl.errors import PlanningError
    from cellctl.geometry.bin_meshes import BinDesign, build_mesh
    from cellctl.planning.mesh import mesh_from_arrays
    from cellctl.surface import FACE_TAG

    if name not in FOREIGN:
        raise PlanningError(f"unknown generated mesh {name!r}; expected one of {list(FOREIGN)}")
    if name == "foreign_basin":
        d = BinDesign(
            name="foreign_basin",
            description="wide low round basin, bulging below a narrow neck, on three legs",
            outline="circle",
            half_x=0.42,
            half_y=0.42,
            sections=((0.0, 0.62, 0.62), (-0.12, 1.0, 1.0), (-0.3, 0.95, 0.95), (-0.45, 0.5, 0.5)),
            hole=("circle", 0.22),
            legs=((0.2, 0.0), (-0.1, 0.17), (-0.1, -0.17)),
            leg_size=0.06,
            leg_top_z=-0.45,
            height=0.7,
            n_perimeter=64,
            row_spacing=0.07,
            top_rings=3,
        )
    else:
        d = BinDesign(
            name="foreign_long",
            description="long narrow bin with a bulge and an inset opening on two skids",
            outline="rect",
            half_x=0.25,
            half_y=0.55,
            sections=((0.0, 1.0, 1.0), (-0.25, 1.12, 1.06), (-0.65, 0.85, 0.9)),
            hole=("inset", 0.07),
            legs=((0.0, -0.38), (0.0, 0.38)),
            leg_size=0.09,
            leg_top_z=-0.65,
            height=0.9,
            n_perimeter=72,
            row_spacing=0.08,
            top_rings=3,
        )
    V, F, S = build_mesh(d)
    return mesh_from_arrays(V, F, name=d.name, internal=S == FACE_TAG["internal"])


def _whole_task(task: tuple[str, int, str, tuple[str, ...], Any]) -> tuple[str, int, dict[str, Any]]:
    """One (bin, seed) whole plan in a worker process (a fresh interpreter per bench run)."""
    from cellctl.geometry.camera import CameraModel
    from cellctl.geometry.catalog import load_catalog
    from cellctl.planning.mesh import load_catalog_mesh
    from cellctl.planning.plan import PlanParams
    from cellctl.planning.robot import default_robot_model
    from cellctl.planning.whole import WholeParams, plan_whole

    name, seed, config, overrides, _ = task
    opts = BenchOptions(n=None, seed=seed, config=config, overrides=overrides, out=None)
    cfg = opts.load_config()
    if name in FOREIGN:
        mesh, bt = foreign_mesh(name), None
    else:
        mesh = load_catalog_mesh(cfg.path(cfg.catalog), name)
        bt = load_catalog(cfg.path(cfg.catalog)).get(name)
    print(f"bench whole-bin: {name} seed {seed}", file=sys.stderr)
    plan_params = PlanParams(seed_pct=cfg.planner.seed_pct, seed=seed, camera=CameraModel.from_config(cfg.camera))
    params = WholeParams.for_cell(cfg, plan_params)  # the arm's own speed and acceleration fractions
    import os

    from cellctl.geometry.robot_model import _quiet_stdout

    with _quiet_stdout():  # ur-analytic-ik's C++ warnings on fd 1 would corrupt the bench's JSON
        plan = plan_whole(mesh, params, default_robot_model(), bin_type=bt)
    # the machine's load over the plan's last minute: what its wall time was measured under
    return name, seed, whole_row(plan, os.getloadavg()[0])


def bench_whole_bin(opts: BenchOptions) -> dict[str, Any]:
    """``cellctl bench whole-bin``: the three catalog bins and two foreign meshes, ≥ 10 seeds each, p_SP 10.

    See :func:`bench_bins` (all bins). With ``--family`` the shape family's meshes instead
    (:func:`cellctl.bench.planning.family.bench_family`)."""
    if opts.family is not None:
        from cellctl.bench.planning.family import bench_family

        return bench_family(opts)
    return bench_bins(opts, None)


def bench_bins(opts: BenchOptions, only: list[str] | None) -> dict[str, Any]:
    """:func:`bench_whole_bin` on ``only`` of its bins (all for None), e.g. the case study alone.

    Per bin: per seed the plan's figures, and median / worst over the seeds. ``--n`` = seeds
    (default 10), ``--seed`` = the first seed. Plans run
    :data:`~cellctl.bench.planning.rows.PROCESSES` at a time (spawned
    processes; each plan evaluates its stations on every core); planning time is reported as
    wall time, CPU seconds (its workers' included) and the load it ran under — on a machine
    shared with other work only the CPU figure is comparable. With ``--out`` the file
    is rewritten after every finished plan (a cut run keeps what it measured).
    """
    import json
    import multiprocessing as mp
    import os
    from concurrent.futures import ProcessPoolExecutor

    from cellctl.geometry.catalog import load_catalog

    cfg = opts.load_config()
    cat = load_catalog(cfg.path(cfg.catalog))
    seeds = list(range(opts.seed, opts.seed + (opts.n or WHOLE_SEEDS)))
    names = [*cat.names, *FOREIGN]
    if only:  # a subset of the bins (e.g. the case study alone for a cycle-time change)
        from cellctl.errors import ConfigError

        unknown = [n for n in only if n not in names]
        if unknown:
            raise ConfigError(f"bench whole-bin: unknown bins {unknown}; known: {names}")
        names = [n for n in names if n in only]
    out: dict[str, Any] = {
        "seed_pct": cfg.planner.seed_pct,
        "seeds": seeds,
        "config": cfg.planner.whole.model_dump(mode="json"),
        "speed_fraction": cfg.robot.speed_fraction,
        "machine": machine_info(),
        "bins": {},
    }
    cfg_path = str(opts.config) if opts.config else None
    # seed-major: a run cut short (its --out file is rewritten after every plan) has every bin at
    # the same number of seeds
    tasks = [(n, s, cfg_path, tuple(opts.overrides), None) for s in seeds for n in names]
    rows: dict[str, dict[int, dict[str, Any]]] = {n: {} for n in names}
    # an executor's workers are not daemonic (a Pool's are): each plan may start its own workers
    with ProcessPoolExecutor(PROCESSES, mp_context=mp.get_context("spawn")) as pool:
        for name, seed, row in pool.map(_whole_task, tasks):
            rows[name][seed] = row
            got = [rows[name][k] for k in sorted(rows[name])]
            out["bins"][name] = {"summary": median_worst(got), "runs": got}
            if opts.out is not None:
                out["machine"]["load_avg_now"] = list(os.getloadavg())
                opts.out.write_text(json.dumps(out, indent=2) + "\n")
    out["machine"]["load_avg_end"] = list(os.getloadavg())
    return out
