"""Where a cycle's powder lies and what its logged wash sweeps did to it: the scenario's powder per face
near a clump, the dirt map's probability of those faces, and the powder left after each round when the
logged `robot/wash` sweeps are sprayed at the bin pose measured before them (the twin's spray model).

    .venv/bin/python tools/wash_powder.py logs/<demo>/<day>/<cycle>.mcap \
        [--seed 18] [--amount 0.01] [--clump -0.43 0.335 -0.585] [--bin case_study]

Demo story 3 (docs/figures/wash_story3_twin_powder.json): the clump lies on the -x side of a leg (faces
4370/4371), which no view saw; the dirt map called the leg's -y side (4365) dirty; no logged sweep
removed the powder on the -x side.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from mcap.reader import make_reader

from cellctl.bus import keys, topics
from cellctl.classify.heatmap import face_probabilities
from cellctl.config import load_config
from cellctl.geometry import robot_model as rm
from cellctl.geometry.catalog import load_catalog
from cellctl.geometry.transforms import invert
from cellctl.messages import PoseMsg
from cellctl.planning.raycast import RayCaster
from cellctl.sim.ground_truth import PowderField
from cellctl.washing.nozzle import NozzleModel
from cellctl.washing.twin import spray_pass


def _pose(d: dict) -> np.ndarray:
    p, q = d["position"], d["orientation"]
    return PoseMsg(position=tuple(p[c] for c in "xyz"), orientation=tuple(q[c] for c in "xyzw")).matrix()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("mcap")
    ap.add_argument("--seed", type=int, default=18)
    ap.add_argument("--amount", type=float, default=0.01)
    ap.add_argument("--clump", type=float, nargs=3, default=(-0.43, 0.335, -0.585))
    ap.add_argument("--bin", default="case_study")
    a = ap.parse_args()
    cfg = load_config()
    nozzle = NozzleModel.from_config(cfg.nozzle)
    mesh = load_catalog(cfg.path(cfg.catalog), cfg.root).load_mesh(a.bin)
    rays = RayCaster(mesh.vertices, mesh.faces)
    field = PowderField.sample(mesh, a.amount, a.seed)
    near = np.flatnonzero(np.linalg.norm(mesh.centroids - np.asarray(a.clump), axis=1) < 0.12)
    rng = np.random.default_rng(1)
    pts, nrm, own = [], [], []
    for f in near:  # 2000-odd points on each face near the clump
        W = mesh.vertices[mesh.faces[f]]
        u = rng.random((4000, 2))
        u = u[u.sum(axis=1) <= 1]
        pts.append(W[0] + u[:, :1] * (W[1] - W[0]) + u[:, 1:] * (W[2] - W[0]))
        nrm.append(np.repeat(mesh.normals[f][None], len(u), axis=0))
        own.append(np.full(len(u), f))
    P, N, F = np.concatenate(pts), np.concatenate(nrm), np.concatenate(own)

    def powder() -> dict[int, float]:
        al = field.alpha(P, mesh.surface[F], N)
        return {int(f): round(float((al[F == f] > 0.5).mean()), 4) for f in near}

    out: dict = {"faces": {int(f): {"normal": mesh.normals[f].round(3).tolist()} for f in near}}
    out["powder_before"] = powder()
    T_base_bin, rounds, maps = None, [], []
    with open(a.mcap, "rb") as fh:
        wanted = [
            topics.BIN_POSE,
            topics.request(keys.worker_op(cfg.cell_id, "robot", "wash")),
            topics.WASH_ROUND,
            topics.request(keys.worker_op(cfg.cell_id, "planner", "wash_plan")),
        ]
        for _s, ch, m in make_reader(fh).iter_messages(topics=wanted):
            d = json.loads(m.data)
            if ch.topic == topics.BIN_POSE:
                T_base_bin = _pose(d["pose"])
            elif ch.topic.endswith("wash_plan/request"):
                p = face_probabilities(d["dirt_map"] or {}, mesh.n_faces)
                if p is not None:
                    fp = {int(f): None if np.isnan(p[f]) else round(float(p[f]), 3) for f in near}
                    maps.append({"round": d["round"], "face_p": fp})
            elif ch.topic == topics.WASH_ROUND:
                rounds.append({"round": d["round"], "passes": len(field.washes), "powder_after": powder()})
            elif T_base_bin is not None:
                T_bin_base = invert(T_base_bin)
                for sw in d["sweeps"]:
                    q = np.asarray(sw["joints"], np.float64)
                    for k in range(sw["passes"]):
                        run = q if k % 2 == 0 else q[::-1]
                        T = T_bin_base @ rm.fk_batch(run) @ nozzle.T_flange_nozzle()
                        field.wash(spray_pass(T, rays, nozzle))
    out["dirt_map_face_p"] = maps
    out["rounds"] = rounds
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
