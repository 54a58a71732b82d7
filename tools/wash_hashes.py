"""Fingerprints of wash plans, to show a refactor of the wash planner left them the same (issue 33).

Usage::

    nice .venv/bin/python tools/wash_hashes.py --out logs/wash_hashes_before.json
    # ... refactor ...
    nice .venv/bin/python tools/wash_hashes.py --compare logs/wash_hashes_before.json

Plans the case-study bin's wash for three dirt maps: the board-side powder spot of
tests/washing/test_plan.py (one station), the demo's round-3 sliver (face 4365, its four stations and
start joints: tests/washing/test_plan_connect.py) and seeded powder all over the bin (one station,
the residue pass at work). The CPU budget is off (``cpu_budget_s`` = inf: how much CPU a station took
decides whether the next one runs, which a loaded machine changes); everything else is the default.
Hashed: every sweep's poses, joints, faces, passes and station, the transits, passes per face, the
covered / washed / target faces, the unwashable pieces, counts and the reason (not the clocks).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

STATIONS = [  # tests/washing/test_plan_connect.py: the round-3 request's measured base poses
    ((-1.19387, 0.10265, -0.32999), (0.000285, -0.0000997, -0.0341276, 0.9994174)),
    ((1.01314, 0.85926, -0.32768), (0.000339, 0.00082, -0.9375757, 0.3477802)),
    ((0.09521, 1.15979, -0.32721), (0.00063, 0.000624, -0.7295842, 0.6838905)),
    ((-0.08222, -1.13887, -0.33172), (0.000593, -0.001028, 0.6808911, 0.7323837)),
]
Q_START = (3.24982, 0.05246, 1.79634, -2.82052, 1.59287, -3.17490)


def fingerprint(plan: Any) -> str:
    h = hashlib.sha256()
    for sw in plan.sweeps:
        for a in (sw.T_bin_noz, sw.q, np.asarray(sw.faces, np.int64)):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(f"{sw.region},{sw.surface},{sw.passes},{sw.station}".encode())
    for a in (plan.dirty, plan.targets, plan.covered, plan.washed, plan.passes, plan.q_start):
        h.update(np.ascontiguousarray(a).tobytes())
    body = {
        "transits": list(plan.transits_free),
        "unwashable": [u.describe() + f": {u.reason}" for u in plan.unwashable],
        "counts": dict(plan.counts),
        "reason": plan.reason,
        "source": plan.source,
    }
    h.update(json.dumps(body, sort_keys=True).encode())
    return h.hexdigest()


def run() -> dict[str, Any]:
    from cellctl.config import load_config
    from cellctl.geometry.catalog import load_catalog
    from cellctl.messages import PoseMsg
    from cellctl.planning.robot import default_robot_model
    from cellctl.sim.ground_truth import PowderField
    from cellctl.sim.scene import nominal_T_bin_base
    from cellctl.surface import EXTERNAL
    from cellctl.washing.nozzle import NozzleModel
    from cellctl.washing.plan import WashParams, plan_wash

    cfg = load_config()
    cat = load_catalog(cfg.path(cfg.catalog), cfg.root)
    mesh = cat.load_mesh("case_study")
    T = nominal_T_bin_base(cat.get("case_study"), mesh)
    robot = default_robot_model()
    poses = [PoseMsg(position=p, orientation=q, frame_id="bin").matrix() for p, q in STATIONS]
    inf = float("inf")
    centre, normal = np.array([(0.2, -0.37, -0.15)]), np.array([(0.0, -1.0, 0.0)])
    spot = PowderField(centre, np.array([0.04]), np.array([EXTERNAL], np.uint8), normal, 7)
    powder = PowderField.sample(mesh, 0.3, 860361905)
    cases = {
        "spot_board_side": (
            {"seen_dirty": np.flatnonzero(spot.dirty_faces(mesh)).tolist()},
            [T],
            NozzleModel(),
            WashParams(cpu_budget_s=inf),
        ),
        "demo_round3_sliver": (
            {"seen_dirty": [4365]},
            poses,
            NozzleModel.from_config(cfg.nozzle),
            WashParams(q_start=Q_START, cpu_budget_s=inf),
        ),
        "powder_residue": (
            {"seen_dirty": np.flatnonzero(powder.dirty_faces(mesh)).tolist()},
            [T],
            NozzleModel(),
            WashParams(cpu_budget_s=inf),
        ),
    }
    out: dict[str, Any] = {}
    for name, (dm, st, nozzle, params) in cases.items():
        t0 = time.perf_counter()
        plan = plan_wash(mesh, dm, st, nozzle, robot, params)
        out[name] = {
            "sha256": fingerprint(plan),
            "sweeps": len(plan.sweeps),
            "covered_faces": int(plan.covered.sum()),
            "wall_s": round(time.perf_counter() - t0, 1),
        }
        print(f"{name}: {out[name]}", file=sys.stderr, flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path)
    ap.add_argument("--compare", type=Path, help="fingerprints of an earlier run: exit 1 on any difference")
    a = ap.parse_args(argv)
    cases = run()
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps({"cases": cases}, indent=1, sort_keys=True))
    if a.compare:
        ref = json.loads(a.compare.read_text())["cases"]
        bad = [k for k in ref if ref[k]["sha256"] != cases.get(k, {}).get("sha256")]
        print(f"{len(ref) - len(bad)}/{len(ref)} wash plans identical" + (f"; different: {bad}" if bad else ""))
        return 1 if bad else 0
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
