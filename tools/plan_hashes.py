"""Fingerprints of the plans the planner makes, to show a refactor left them byte-identical (issue 33).

Usage::

    nice .venv/bin/python tools/plan_hashes.py --out logs/plan_hashes_before.json
    # ... refactor ...
    nice .venv/bin/python tools/plan_hashes.py --compare logs/plan_hashes_before.json

Plans each catalog bin (``config/bins.yaml``) whole-bin (``cellctl plan --whole``'s parameters from
``config/cell.yaml``) and single-station (both surfaces, one fixed base pose per bin) for the given
seeds, writes the plan files as ``cellctl plan`` does into a temporary plan cache, and records the
sha256 of every file. Three things in a plan file are not the planner's output and are pinned or
blanked before hashing, so two runs of the same code hash the same:

- ``plan_id`` is ``uuid4()``: replaced by a counter (the n-th id this case drew), so file names
  and the station → plan references stay comparable;
- ``created`` and every ``times_s`` (wall and CPU seconds) and the exact covers' ``seconds``: blanked;
  the files are re-enveloped (``write_document``) after blanking, so the envelope hash is hashed too;
- HiGHS' MILP ``time_limit`` (a wall-clock limit: on a loaded machine a cover that hits it answers
  differently) is raised to ``--milp-limit`` seconds for both runs.

Whole plans run in process (``workers=1``: the same plan as any number of workers, tested in
tests/planning/test_whole.py) so one process's ids come in one order.
"""

from __future__ import annotations

import argparse
import hashlib
import itertools
import json
import sys
import tempfile
import time
import uuid
from dataclasses import replace
from pathlib import Path
from typing import Any

VOLATILE = {"created", "times_s"}
"""Keys whose values are clocks, not plans."""

SINGLE_LIMITS = {"fallback_budget_s": 5.0, "simplify_s": 1.0}
"""Single-station plans: RRTConnect's and the path simplification's wall-clock limits (0.2 / 0.05 s) raised so
that a loaded machine does not cut a query short (with OMPL's seed pinned, the query then answers the same)."""

BASES = {"case_study": (0.0, -1.13, -0.33, 90.0), "drum": (0.0, -0.95, -0.3, 90.0), "tote": (0.0, -1.15, -0.3, 90.0)}
"""A single-station base pose per catalog bin (x, y, z m, yaw deg in the bin frame): beside its front."""


def _blank(obj: Any, key: str = "") -> Any:
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            if k in VOLATILE or (k == "seconds" and key in ("exact_cover", "exact")):
                out[k] = None
            else:
                out[k] = _blank(v, k)
        return out
    if isinstance(obj, list):
        return [_blank(v, key) for v in obj]
    return obj


_ids = itertools.count()


def _pin_clocks(milp_limit: float) -> None:
    def uuid4() -> uuid.UUID:
        return uuid.UUID(int=next(_ids) << 80)

    uuid.uuid4 = uuid4  # type: ignore[assignment]  # the checker's own process only
    import scipy.optimize as so

    real = so.milp

    def milp(*args: Any, options: dict[str, Any] | None = None, **kw: Any) -> Any:
        opts = dict(options or {})
        if "time_limit" in opts:
            opts["time_limit"] = max(float(opts["time_limit"]), milp_limit)
        return real(*args, options=opts, **kw)

    so.milp = milp  # the planners import it inside their functions, so they pick this one


def _hash_tree(root: Path) -> dict[str, str]:
    from cellctl.planning.planfile import read_document, write_document

    out = {}
    for p in sorted(root.rglob("*.json")):
        write_document(_blank(read_document(p)), p)
        out[str(p.relative_to(root))] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def run(
    bins: list[str], seeds: list[int], kinds: list[str], config: str | None, out: Path | None = None
) -> dict[str, Any]:
    from ompl import util as ou

    from cellctl.config import load_config
    from cellctl.geometry.camera import CameraModel
    from cellctl.geometry.catalog import load_catalog
    from cellctl.geometry.robot_model import _quiet_stdout
    from cellctl.planning.mesh import load_catalog_mesh
    from cellctl.planning.pipeline import PlanParams, base_pose_from_xyz_yaw, make_plan
    from cellctl.planning.planfile import plan_path, write_plan
    from cellctl.planning.robot import RobotModel
    from cellctl.planning.whole import WholeParams, plan_whole, write_whole
    from cellctl.surface import SURFACES

    ou.RNG.setSeed(1)  # RRTConnect (single-station fast mode, colliding straight moves) draws from OMPL's RNG
    cfg = load_config(config)
    pc = cfg.planner
    cat = load_catalog(cfg.path(cfg.catalog), verify_meshes=False)
    robot = RobotModel.from_config(cfg)
    camera = CameraModel.from_config(cfg.camera)
    cases: dict[str, Any] = {}
    for name, seed, kind in itertools.product(bins, seeds, kinds):
        global _ids
        _ids = itertools.count()  # every case's ids from 0: a case hashes the same whatever ran before it
        mesh = load_catalog_mesh(cfg.path(cfg.catalog), name)
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory() as d:
            if kind == "whole":
                pp = PlanParams(seed_pct=pc.seed_pct, mode="fast", seed=seed, camera=camera)
                params = WholeParams.for_cell(cfg, pp)
                params = replace(params, workers=1)
                with _quiet_stdout():
                    plan = plan_whole(mesh, params, robot, bin_type=cat.get(name))
                write_whole(plan, d)
                budget = {k: v for k, v in plan.counts.items() if k.startswith("budget_")}
                summary = f"{len(plan.stations)} stations, {plan.cycle_time_s:.1f} s, budget steps {budget}"
            else:
                vps = []
                for surf in SURFACES:
                    pp = PlanParams(
                        surface=surf, seed_pct=pc.seed_pct, mode="fast", seed=seed, camera=camera, **SINGLE_LIMITS
                    )
                    with _quiet_stdout():
                        p = make_plan(mesh, base_pose_from_xyz_yaw(*BASES[name]), pp, robot, bin_type=name)
                    write_plan(p, plan_path(d, p))
                    vps.append(f"{surf} {len(p.viewpoints)}")
                summary = ", ".join(vps) + " viewpoints"
            files = _hash_tree(Path(d))
        key = f"{name}/seed{seed}/{kind}"
        whole = hashlib.sha256(json.dumps(files, sort_keys=True).encode()).hexdigest()
        cases[key] = {"sha256": whole, "files": files, "summary": summary, "wall_s": round(time.perf_counter() - t0, 1)}
        print(f"{key}: {whole[:16]} ({summary}; {cases[key]['wall_s']} s)", file=sys.stderr, flush=True)
        if out is not None:  # after every case: a long run cut short keeps what it did
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(json.dumps({"cases": cases}, indent=1, sort_keys=True))
    return cases


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bins", nargs="+", default=["case_study", "drum", "tote"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--kinds", nargs="+", choices=["whole", "single"], default=["whole", "single"])
    ap.add_argument("--config", default=None, help="cell config (default config/cell.yaml)")
    ap.add_argument("--milp-limit", type=float, default=120.0, help="HiGHS time limit floor, s")
    ap.add_argument("--out", type=Path, help="write the fingerprints here (JSON, after every case)")
    ap.add_argument("--compare", type=Path, help="fingerprints of an earlier run: exit 1 on any difference")
    ap.add_argument("--against", type=Path, help="with --compare: compare this file instead of planning")
    a = ap.parse_args(argv)
    if a.against:
        cases = json.loads(a.against.read_text())["cases"]
    else:
        _pin_clocks(a.milp_limit)
        cases = run(a.bins, a.seeds, a.kinds, a.config, a.out)
    if not a.compare:
        return 0
    ref = json.loads(a.compare.read_text())["cases"]
    both = sorted(set(ref) & set(cases))
    bad = [k for k in both if ref[k]["sha256"] != cases[k]["sha256"]]
    for k in bad:
        x, y = ref[k]["files"], cases[k]["files"]
        print(f"DIFFERENT {k}: {sorted(f for f in set(x) | set(y) if x.get(f) != y.get(f))}", file=sys.stderr)
    print(f"{len(both) - len(bad)}/{len(both)} cases identical: {', '.join(k for k in both if k not in bad)}")
    return 1 if bad or not both else 0


if __name__ == "__main__":
    raise SystemExit(main())
