"""A surface's arm-free bound over the fixed-distance viewpoints only (before the opening views), per family mesh.

Usage::

    nice .venv/bin/python tools/fixed_distance_bound.py --family mixed:0-11 --out logs/fixed_bound.json

The whole planner's arm-free bound is the area properly visible from any filtered candidate camera
pose; since the internal opening views (``PlanParams.opening_views``, issue 35) the candidate set is
larger, so the bound is larger on deep cavities (cameras in and above the opening see more) and a plan
that sees the same faces reads as a smaller % of it. This prints, per mesh and surface, the bound of
both candidate sets (``opening_views`` off and on) with the planner's parameters (``config/cell.yaml``),
so a bench row's seen area can be put against the earlier yardstick too.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace

import numpy as np


def main(argv: list[str] | None = None) -> int:
    from cellctl.bench.options import BenchOptions
    from cellctl.bench.planning.family import parse_family
    from cellctl.geometry.camera import CameraModel
    from cellctl.geometry.family import family_mesh
    from cellctl.geometry.transforms import invert
    from cellctl.planning import pipeline as pl
    from cellctl.planning.collision import PlanningWorld
    from cellctl.planning.plan import PlanParams
    from cellctl.planning.raycast import RayCaster
    from cellctl.planning.robot import default_robot_model
    from cellctl.planning.stations import candidate_stations
    from cellctl.planning.visibility import measurability
    from cellctl.planning.whole import WholeParams
    from cellctl.surface import SURFACES

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--family", default="mixed:0-11")
    ap.add_argument("--surface", default="internal", choices=SURFACES)
    ap.add_argument("--seeds", default="0", help="planner seeds (the seed points differ per seed), comma-separated")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    family, meshes = parse_family(a.family)
    cfg = BenchOptions(n=None, seed=0, config=None, overrides=(), out=None).load_config()
    robot = default_robot_model()
    out: dict[str, dict[str, dict[str, float]]] = {}
    for m in meshes:
        mesh = family_mesh(family, m)
        rays = RayCaster(mesh.vertices, mesh.faces)
        sf = np.flatnonzero(mesh.surface_mask(a.surface))
        A = mesh.areas[sf]
        for seed in (int(s) for s in a.seeds.split(",")):
            p0 = PlanParams(seed_pct=cfg.planner.seed_pct, seed=seed, camera=CameraModel.from_config(cfg.camera))
            params = WholeParams.for_cell(cfg, p0)
            ref = next(c for c in candidate_stations(mesh, None, params.stations) if c.reason is None).T_bin_base
            row = {"area_m2": float(A.sum())}
            for on in (False, True):
                p = replace(p0, surface=a.surface, max_reach=1.0e3, opening_views=on)
                rng = np.random.default_rng([seed, SURFACES.index(a.surface)])  # the whole planner's stream
                world = PlanningWorld(mesh, robot, ref, margin=p.margin)
                s = pl.Setup(mesh, robot, p, ref, invert(ref), np.asarray(robot.q_home), sf, world, rays, rng)
                st = pl._Stages(None, False)
                st.start("generate_filter", "generate+filter")
                filt = pl.generate_and_filter(s, st)
                seen = measurability(filt.vp.T, mesh, sf, p.camera, rays).any(axis=1)
                row["bound_m2_opening_views" if on else "bound_m2_fixed_distances"] = float(A[seen].sum())
            out.setdefault(mesh.name, {})[str(seed)] = row
            print(mesh.name, seed, json.dumps(row), flush=True)
    if a.out:
        with open(a.out, "w") as f:
            f.write(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
