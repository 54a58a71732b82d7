"""Replan a cycle's logged wash plans: each `wash_plan` request in a cycle MCAP, planned again by this
checkout's `plan_wash`, with what the demo's story 3 needed checked (docs/figures/wash_story3_plans.json).

    .venv/bin/python tools/wash_replan.py logs/<demo>/<day>/<cycle>.mcap [--seed 18]

Per request: sweeps, how many have an end a straight free motion from home reaches (0.02 rad checks),
the shoulder's range, covered / target area, and — over the scenario's powder (`--seed`, amount 0.01, the
demo's) — the powder left on face 4365 within the clump at (-0.43, 0.335, -0.585) after the plan's sweeps.
Run it from the checkout root (PYTHONPATH=<an exported tree> to measure another commit).
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from mcap.reader import make_reader

from cellctl.config import load_config
from cellctl.geometry.catalog import load_catalog
from cellctl.messages import WashPlanRequest
from cellctl.planning.collision import PlanningWorld
from cellctl.planning.robot import default_robot_model
from cellctl.sim.ground_truth import PowderField
from cellctl.washing.nozzle import NozzleModel
from cellctl.washing.plan import WashParams, plan_wash
from cellctl.washing.twin import wash_in_twin

FACE, CLUMP = 4365, (-0.43, 0.335, -0.585)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("mcap")
    ap.add_argument("--seed", type=int, default=18)
    args = ap.parse_args()
    cfg = load_config()
    nozzle, robot = NozzleModel.from_config(cfg.nozzle), default_robot_model()
    tool = nozzle.robot_with_nozzle(robot)
    catalog = load_catalog(cfg.path(cfg.catalog), cfg.root)
    with open(args.mcap, "rb") as fh:
        reqs = [
            WashPlanRequest(**json.loads(m.data))
            for _s, ch, m in make_reader(fh).iter_messages()
            if ch.topic.endswith("/planner/wash_plan/request")
        ]
    rows = []
    for req in reqs:
        mesh = catalog.load_mesh(req.bin_type)
        p = WashParams(threshold=req.threshold, margin_m=req.margin_m, q_start=tuple(req.q_start))
        plan = plan_wash(mesh, req.dirt_map, [s.matrix() for s in req.stations], nozzle, robot, p)
        home = 0
        for sw in plan.sweeps:
            w = PlanningWorld(mesh, tool, plan.stations[sw.station], margin=0.005)
            ends = w.motion_free(np.repeat(robot.q_home[None], 2, axis=0), sw.q[[0, -1]], 0.02)
            home += bool(ends.any())
        field = PowderField.sample(mesh, 0.01, args.seed)
        wash_in_twin(field, plan, mesh, nozzle)
        V = mesh.vertices[mesh.faces[FACE]]
        u = np.random.default_rng(0).random((4000, 2))
        u = u[u.sum(axis=1) <= 1]
        P = V[0] + u[:, :1] * (V[1] - V[0]) + u[:, 1:] * (V[2] - V[0])
        k = int(np.argmin(np.linalg.norm(field.centres - CLUMP, axis=1)))
        P = P[np.linalg.norm(P - field.centres[k], axis=1) <= field.radii[k]]
        left = field.remaining(P, np.repeat(mesh.normals[FACE][None], len(P), axis=0)) if len(P) else np.zeros(0)
        s = plan.summary(mesh)
        q1 = [float(x) for sw in plan.sweeps for x in (sw.q[:, 1].min(), sw.q[:, 1].max())]
        rows.append(
            {
                "round": req.round,
                "stations": len(req.stations),
                "sweeps": len(plan.sweeps),
                "sweeps_with_an_end_straight_from_home": home,
                "shoulder_range_rad": [round(min(q1), 2), round(max(q1), 2)] if q1 else None,
                "covered_cm2": round(s["covered_m2"] * 1e4),
                "target_cm2": round(s["target_m2"] * 1e4),
                "sliver_powder_left_mean": round(float(left.mean()), 4) if len(left) else None,
                "unwashable": [(u["faces"], round(u["area_m2"] * 1e4)) for u in s["unwashable"]],
            }
        )
    print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
