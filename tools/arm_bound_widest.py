"""Per-stage counts and the arm-aware bound over the widest station set, for one family mesh (issue 35).

Usage::

    nice .venv/bin/python tools/arm_bound_widest.py --mesh mixed:7 --surface internal \
        --rings 0.23,0.35,0.5,0.75 --directions 8 --out logs/arm_bound_mixed_7.json

The whole planner evaluates its configured candidate stations (``planner.whole``: an outer ring at
``park_distance_m`` and an inner one at ``inner_park_distance_m``). Where a mesh's internal coverage
stays below 70 % of the arm-free bound, issue 35 asks whether *any* placement of this arm could do
better: this tool evaluates every station on several rings (``--rings``: metres beyond the bin's
extent; the closest the mobile base box allows is about 0.23 m) and ``--directions`` directions each
(8: the sides and the corners), with the planner's own stages and parameters (``config/cell.yaml``),
and reports per station the viewpoints left after each stage — generated → filtered (height,
occlusion, camera body) → within reach → IK-reachable and collision-free (parking-robust) →
connected to home — and the area each stage's viewpoints properly see; then the union over all
stations (the widest arm-aware bound) beside the arm-free bound. The base height is fixed (the arm on
its mobile base, ``BASE_HEIGHT_M``), and the camera mount is the configured one (``robot.hand_eye``,
else the nominal mount): the cell offers no other.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace

import numpy as np

COARSE_STEP_RAD = 0.02  # the whole planner's connection check step (cellctl.planning.whole)


def main(argv: list[str] | None = None) -> int:
    from cellctl.bench.options import BenchOptions
    from cellctl.geometry.camera import CameraModel
    from cellctl.geometry.family import family_mesh
    from cellctl.geometry.robot_model import _quiet_stdout
    from cellctl.geometry.transforms import invert
    from cellctl.planning import pipeline as pl
    from cellctl.planning.collision import PlanningWorld
    from cellctl.planning.filters import distance_filter
    from cellctl.planning.plan import PlanParams
    from cellctl.planning.raycast import RayCaster
    from cellctl.planning.reach import robust_acceptor
    from cellctl.planning.robot import default_robot_model
    from cellctl.planning.stations import candidate_stations
    from cellctl.planning.visibility import measurability
    from cellctl.planning.whole import WholeParams, connect, wrap_window
    from cellctl.surface import SURFACES

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", required=True, help="family mesh F:S, e.g. mixed:7")
    ap.add_argument("--surface", default="internal", choices=SURFACES)
    ap.add_argument("--rings", default="0.23,0.35,0.5,0.75", help="m beyond the bin's extent, comma-separated")
    ap.add_argument("--directions", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    family, _, mesh_seed = a.mesh.partition(":")
    cfg = BenchOptions(n=None, seed=a.seed, config=None, overrides=(), out=None).load_config()
    mesh = family_mesh(family, int(mesh_seed))
    p0 = PlanParams(seed_pct=cfg.planner.seed_pct, seed=a.seed, camera=CameraModel.from_config(cfg.camera))
    params = WholeParams.for_cell(cfg, p0)
    robot = default_robot_model()
    q_home = np.asarray(robot.q_home, dtype=np.float64)
    rays = RayCaster(mesh.vertices, mesh.faces)
    sf = np.flatnonzero(mesh.surface_mask(a.surface))
    A = mesh.areas[sf]
    cands = []
    for r in (float(x) for x in a.rings.split(",")):
        sp = replace(params.stations, park_distance_m=r, candidates=a.directions, inner_candidates=0)
        cands += [(r, c) for c in candidate_stations(mesh, None, sp) if c.reason is None]
    ref = cands[0][1].T_bin_base
    p = replace(p0, surface=a.surface, max_reach=1.0e3)
    rng = np.random.default_rng([p0.seed, SURFACES.index(a.surface)])
    world0 = PlanningWorld(mesh, robot, ref, margin=p.margin)
    s = pl.Setup(mesh, robot, p, ref, invert(ref), q_home, sf, world0, rays, rng)
    st = pl._Stages(None, False)
    st.start("generate_filter", "generate+filter")
    filt = pl.generate_and_filter(s, st)
    bound = A[measurability(filt.vp.T, mesh, sf, p.camera, rays).any(axis=1)].sum()
    out = {
        "mesh": mesh.name,
        "surface": a.surface,
        "area_m2": float(A.sum()),
        "bound_m2": float(bound),
        "generated": filt.generated,
        "after_height": filt.after_height,
        "after_occlusion": filt.after_occlusion,
        "filtered": filt.after_camera_collision,
        "stations": [],
    }
    seen_reached = np.zeros(len(sf), dtype=bool)
    seen_connected = np.zeros(len(sf), dtype=bool)
    for r, c in cands:
        world = PlanningWorld(mesh, robot, c.T_bin_base, margin=p0.margin)
        sc = pl.Setup(
            mesh,
            robot,
            replace(p0, surface=a.surface),
            c.T_bin_base,
            invert(c.T_bin_base),
            q_home,
            sf,
            world,
            rays,
            rng,
        )
        near = distance_filter(filt.vp, c.T_bin_base[:3, 3], sc.params.max_reach)
        vp = filt.vp.subset(np.flatnonzero(near))
        st = pl._Stages(None, False)
        st.start("reachability", "reachability")
        with _quiet_stdout():
            found = pl.reach(sc, vp, st).reached
        Cr = measurability(found.T, mesh, sf, p.camera, rays).any(axis=1)
        wrap = wrap_window(found.q, robot, q_home)
        found.q[:] = wrap(found.q)
        accept = robust_acceptor(mesh, robot, c.T_bin_base, p0)
        con = connect(vp, found, robot, world, invert(c.T_bin_base), q_home, p0.n_roll, accept, COARSE_STEP_RAD, wrap)
        Cc = measurability(con.reached.T, mesh, sf, p.camera, rays).any(axis=1)
        seen_reached |= Cr
        seen_connected |= Cc
        row = {
            "ring_m": r,
            "angle_deg": round(c.angle_deg, 1),
            "within_reach": int(near.sum()),
            "directions": int(len(np.unique(vp.seed))),
            "reachable": int(len(found.index)),
            "reachable_sees_m2": float(A[Cr].sum()),
            "connected": int(len(con.reached.index)),
            "connected_sees_m2": float(A[Cc].sum()),
        }
        out["stations"].append(row)
        print(json.dumps(row), file=sys.stderr)
    out["widest_reachable_m2"] = float(A[seen_reached].sum())
    out["widest_arm_bound_m2"] = float(A[seen_connected].sum())
    out["widest_arm_bound_of_bound"] = float(A[seen_connected].sum() / bound) if bound > 0 else 0.0
    text = json.dumps(out, indent=1)
    if a.out:
        with open(a.out, "w") as f:
            f.write(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
