"""``cellctl bench whole-bin --family [F[:A-B]]``: whole-bin plans of the shape family's meshes
(:mod:`cellctl.geometry.family`, meshes A..B of family F, default ``mixed:0-11``) over planner seeds
(``--n``, default 3; ``--seed`` the first).

Per mesh and seed the figures of ``bench whole-bin`` (:func:`cellctl.bench.planning.rows.whole_row`),
and beside each surface's bound fraction its **arm-aware** one (seen / the area some reachable,
collision-free camera pose sees from any candidate station) and the arm-aware bound's share of the
arm-free bound (``arm_bound_of_bound``: below 1, "no arm at these stations could"); the cycle time
per m² of inspected (seen) surface. The meshes are listed worst first (lowest worst bound fraction
of any surface). With ``--out`` the JSON is rewritten after every plan, and one internal coverage
picture per mesh (its first seed, cut open: :func:`cellctl.planning.whole_render.render_whole`)
goes to ``<out stem>_png/``.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from cellctl.bench.options import BenchOptions
from cellctl.errors import ConfigError
from cellctl.surface import SURFACES

__all__ = ["FAMILY_MESHES", "FAMILY_SEEDS", "bench_family", "parse_family"]

FAMILY_MESHES = 12
"""Meshes of the family benched by default (seeds 0..11 of the generator)."""
FAMILY_SEEDS = 3
"""Planner seeds per mesh (``--n`` overrides)."""


def parse_family(spec: str) -> tuple[str, list[int]]:
    """``F`` or ``F:A-B`` or ``F:A`` → the family and its mesh seeds.

    Raises:
        ConfigError: an unknown family or a bad range.
    """
    from cellctl.geometry.family import FAMILIES

    name, _, rng = spec.partition(":")
    if name not in FAMILIES:
        raise ConfigError(f"--family {spec!r}: family {name!r} is unknown; expected one of {sorted(FAMILIES)}")
    if not rng:
        return name, list(range(FAMILY_MESHES))
    lo, _, hi = rng.partition("-")
    try:
        a, b = int(lo), int(hi or lo)
    except ValueError as err:
        raise ConfigError(f"--family {spec!r}: mesh range {rng!r} must be A or A-B (integers)") from err
    if not 0 <= a <= b:
        raise ConfigError(f"--family {spec!r}: mesh range {rng!r} must have 0 <= A <= B")
    return name, list(range(a, b + 1))


def _family_row(plan: Any, load: float) -> dict[str, Any]:
    from cellctl.bench.planning.rows import whole_row

    row = whole_row(plan, load)
    seen = 0.0
    for k, v in plan.surfaces.items():
        if v.reason is None:
            row["surfaces"][k]["arm_bound_fraction"] = v.arm_bound_fraction
            row["surfaces"][k]["arm_bound_of_bound"] = v.reachable_m2 / v.bound_m2 if v.bound_m2 > 0 else 0.0
            row["surfaces"][k]["area_m2"] = v.area_m2
            seen += v.seen_m2
    row["seen_m2"] = seen
    row["cycle_s_per_m2"] = plan.cycle_time_s / seen if seen > 0 else None
    return row


def _family_task(
    task: tuple[str, int, int, str | None, tuple[str, ...], str | None],
) -> tuple[str, int, dict[str, Any]]:
    """One (mesh, planner seed) whole plan in a worker process; the mesh's first seed also draws
    its pictures into ``png_dir``."""
    import os

    from cellctl.geometry.camera import CameraModel
    from cellctl.geometry.family import family_mesh
    from cellctl.geometry.robot_model import _quiet_stdout
    from cellctl.planning.plan import PlanParams
    from cellctl.planning.robot import default_robot_model
    from cellctl.planning.whole import WholeParams, plan_whole

    family, mesh_seed, seed, config, overrides, png_dir = task
    opts = BenchOptions(n=None, seed=seed, config=config, overrides=overrides, out=None)
    cfg = opts.load_config()
    mesh = family_mesh(family, mesh_seed)
    print(f"bench whole-bin --family: {mesh.name} seed {seed}", file=sys.stderr)
    plan_params = PlanParams(seed_pct=cfg.planner.seed_pct, seed=seed, camera=CameraModel.from_config(cfg.camera))
    params = WholeParams.for_cell(cfg, plan_params)
    with _quiet_stdout():  # ur-analytic-ik's C++ warnings on fd 1 would corrupt the bench's JSON
        plan = plan_whole(mesh, params, default_robot_model())
    row = _family_row(plan, os.getloadavg()[0])
    if png_dir is not None and not plan.is_empty:
        from cellctl.planning.whole_render import render_whole

        row["pictures"] = [str(p) for p in render_whole(plan, mesh, Path(png_dir) / f"{mesh.name}_seed{seed}.png")]
    return mesh.name, seed, row


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """:func:`cellctl.bench.planning.rows.median_worst` plus the arm-aware fractions and cycle s/m²."""
    import numpy as np

    from cellctl.bench.planning.rows import median_worst

    out = median_worst(rows)
    for surf, s in out.items():
        if not isinstance(s, dict) or "bound_fraction" not in s:
            continue
        got = [r["surfaces"][surf] for r in rows if r["surfaces"][surf]["reason"] is None]
        for key in ("arm_bound_fraction", "arm_bound_of_bound"):
            a = np.asarray([g[key] for g in got], dtype=float)
            s[key] = {"median": float(np.median(a)), "worst": float(a.min())}
    per = np.asarray([r["cycle_s_per_m2"] for r in rows if r["cycle_s_per_m2"] is not None], dtype=float)
    out["cycle_s_per_m2"] = {"median": float(np.median(per)), "worst": float(per.max())} if len(per) else None
    return out


def _worst_key(entry: dict[str, Any]) -> float:
    """The lowest worst-seed bound fraction of any planned surface (a failed plan: -1)."""
    s = entry["summary"]
    fr = [v["bound_fraction"]["worst"] for v in s.values() if isinstance(v, dict) and "bound_fraction" in v]
    return min(fr) if fr else -1.0


def table(meshes: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """One compact row per mesh, worst first: the closing note's table (medians / worst over seeds)."""

    def mw(d: dict[str, Any] | None, pct: bool = True) -> str | None:
        if d is None:
            return None
        f = 100.0 if pct else 1.0
        return f"{f * d['median']:.1f}/{f * d['worst']:.1f}"

    rows = []
    for name, e in sorted(meshes.items(), key=lambda kv: _worst_key(kv[1])):
        s = e["summary"]
        r: dict[str, Any] = {"mesh": name, "shape": e["shape"], "stations": mw(s["stations"], False)}
        for surf in SURFACES:
            v = s.get(surf, {})
            if "bound_fraction" not in v:
                r[surf] = v.get("reason")
                continue
            r[surf] = {
                "pct_bound": mw(v["bound_fraction"]),
                "pct_arm_bound": mw(v["arm_bound_fraction"]),
                "arm_bound_pct_of_bound": mw(v["arm_bound_of_bound"]),
            }
        r.update(
            viewpoints=mw(s["viewpoints"], False),
            planning_wall_s=mw(s["planning_s"], False),
            planning_cpu_s=mw(s["planning_cpu_s"], False),
            cycle_s=mw(s["cycle_time_s"], False),
            cycle_s_per_m2=mw(s["cycle_s_per_m2"], False),
            dropped=mw(s["dropped_unconnected"], False),
            unverified=mw(s["unverified_moves"], False),
        )
        rows.append(r)
    return rows


def bench_family(opts: BenchOptions) -> dict[str, Any]:
    """See the module doc. Plans run one at a time (each plan uses every core for its stations)."""
    import json
    import multiprocessing as mp
    import os
    from concurrent.futures import ProcessPoolExecutor

    from cellctl.bench.planning.rows import PROCESSES, machine_info
    from cellctl.geometry.family import build_family_mesh, draw_params

    family, mesh_seeds = parse_family(opts.family or "mixed")
    cfg = opts.load_config()
    seeds = list(range(opts.seed, opts.seed + (opts.n or FAMILY_SEEDS)))
    png_dir = None
    if opts.out is not None:
        png_dir = str(opts.out.parent / f"{opts.out.stem}_png")
    out: dict[str, Any] = {
        "family": family,
        "mesh_seeds": mesh_seeds,
        "seeds": seeds,
        "command": f"cellctl bench whole-bin --family {opts.family} --n {len(seeds)} --seed {opts.seed}",
        "seed_pct": cfg.planner.seed_pct,
        "config": cfg.planner.whole.model_dump(mode="json"),
        "machine": machine_info(),
        "table": [],
        "meshes": {},
    }
    cfg_path = str(opts.config) if opts.config else None
    # seed-major: a run cut short has every mesh at the same number of seeds
    tasks = [
        (family, m, s, cfg_path, tuple(opts.overrides), png_dir if s == seeds[0] else None)
        for s in seeds
        for m in mesh_seeds
    ]
    rows: dict[str, dict[int, dict[str, Any]]] = {}
    extents = {}
    for m in mesh_seeds:
        V, _, _ = build_family_mesh(draw_params(family, m))
        extents[f"{family}_{m}"] = [round(float(x), 4) for x in V.max(axis=0) - V.min(axis=0)]
    with ProcessPoolExecutor(PROCESSES, mp_context=mp.get_context("spawn")) as pool:
        for name, seed, row in pool.map(_family_task, tasks):
            rows.setdefault(name, {})[seed] = row
            got = [rows[name][k] for k in sorted(rows[name])]
            p = draw_params(family, int(name.rsplit("_", 1)[1]))
            out["meshes"][name] = {
                "params": p.to_json(),
                "extent_m": extents[name],
                "shape": _shape(p.choices),
                "summary": _summary(got),
                "runs": got,
            }
            out["meshes"] = dict(sorted(out["meshes"].items(), key=lambda kv: _worst_key(kv[1])))
            out["table"] = table(out["meshes"])
            if opts.out is not None:
                out["machine"]["load_avg_now"] = list(os.getloadavg())
                opts.out.write_text(json.dumps(out, indent=2) + "\n")
    out["machine"]["load_avg_end"] = list(os.getloadavg())
    return out


def _shape(choices: dict[str, str]) -> str:
    """The drawn options in a few words (``none`` left out)."""
    return " ".join(v for v in choices.values() if v not in ("none", "centred"))
