"""``cellctl bench wash``: wash-and-verify rounds on seeded dirty twin bins.

Per cycle (``--cycles N``, default 6): a catalog bin (the types in turn), seeded powder
(:class:`cellctl.sim.ground_truth.PowderField`, amount uniform in 0.3–1), the usable station
candidates around it (:func:`cellctl.planning.stations.candidate_stations`, ``planner.whole``
config). Each round: a dirt map → :func:`~cellctl.washing.plan.plan_wash` → the passes run in
the twin (:func:`~cellctl.washing.twin.wash_in_twin`) → the twin's powder after; up to
``wash.max_rounds`` rounds, stopping when no dirt is left on faces a nozzle reaches.

Two sets of bins from the same seeds:

* **washable** (the top-level figures): each bin with only the clumps whose faces a nozzle
  reaches (:func:`washable_only`), so ``bins_clean_fraction`` measures the issue's target,
  "every bin whose dirt lies on faces a nozzle reaches ends clean within the configured rounds";
* **mixed** (``"mixed"``): the bins as sampled, powder also where no nozzle pose reaches
  (hopper bottoms, drum floors, legs): those end ``dirty`` with the unwashable pieces.

The dirt map is **derived from the ground truth** (``dirt_source`` says so): ``face_p`` = the
largest powder opacity at a face's centroid and corners, so the faces at or above the wash
threshold are the twin's dirty faces. The detector is not run here: a re-inspection per round
renders and classifies tens of views, minutes per round on the CPUs this bench runs on (the
supervisor's wash_and_verify cycle does re-inspect with the classifier).

Reachable faces: the faces a plan with 12 rolls (three times the production planner's) and
no CPU budget on its residue pass from the same stations sprays, joined with the production
plans'; ``dirty_area_covered`` is the share of the first round's dirty area on reachable faces
the production plan covers.

Pictures (when ``--out`` is given): per round of the first two cycles, ``docs/washing/``
``wash_<set><cycle>_r<round>_{before,path,after}.png`` (set ``c`` mixed, ``w`` washable).
"""

from __future__ import annotations

import logging
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from cellctl.bench.options import BenchOptions

__all__ = ["bench_wash", "gt_dirt_map", "washable_only"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

PICTURE_CYCLES = 2


def gt_dirt_map(field: Any, mesh: Any) -> dict[str, Any]:
    """A dirt map from the twin's powder: ``face_p`` = largest opacity at centroid and corners."""
    from cellctl.classify.heatmap import FaceMap

    tri = mesh.vertices[mesh.faces]
    pts = np.concatenate([tri.mean(axis=1), tri[:, 0], tri[:, 1], tri[:, 2]])
    a = field.alpha(pts, np.tile(mesh.surface, 4), np.tile(mesh.normals, (4, 1))).reshape(4, -1).max(axis=0)
    dirty = a > 0.5
    fm = FaceMap(p=a, seen=np.ones(mesh.n_faces, bool), dirty=dirty, dirty_area_m2=float(mesh.areas[dirty].sum()))
    return fm.as_json()


def washable_only(field: Any, mesh: Any, reach: np.ndarray) -> Any:  # PowderField
    """The same powder with only the clumps whose every dirty face lies in ``reach`` (F,) bool.

    A clump touches the faces with a centroid or corner within one radius of its centre on its
    surface; clumps touching an unreachable face are dropped, then again those near any dirty
    face the smaller field still has outside ``reach`` (clump halos are ragged).
    """
    from scipy.spatial import cKDTree

    from cellctl.sim.ground_truth import PowderField

    tri = mesh.vertices[mesh.faces]
    pts = np.concatenate([tri.mean(axis=1), tri[:, 0], tri[:, 1], tri[:, 2]])
    owner = np.tile(np.arange(mesh.n_faces), 4)
    tree = cKDTree(pts)
    keep = np.ones(len(field.radii), bool)
    for j, (c, r, tag) in enumerate(zip(field.centres, field.radii, field.surface, strict=True)):
        faces = owner[np.asarray(tree.query_ball_point(c, 1.0 * r), np.int64)]
        faces = faces[mesh.surface[faces] == tag]
        keep[j] = bool(reach[faces].all())

    def sub() -> Any:
        return PowderField(field.centres[keep], field.radii[keep], field.surface[keep], field.normals[keep], field.seed)

    for _ in range(4):
        bad = sub().dirty_faces(mesh) & ~reach
        if not bad.any() or not keep.any():
            break
        d, _ = cKDTree(mesh.centroids[bad]).query(field.centres)
        keep &= d > 2.0 * field.radii
    return sub()


def bench_wash(opts: BenchOptions) -> dict[str, Any]:
    from cellctl.geometry.catalog import load_catalog, read_bin_mesh
    from cellctl.planning.robot import default_robot_model
    from cellctl.planning.stations import StationParams, candidate_stations
    from cellctl.sim.ground_truth import PowderField
    from cellctl.washing.nozzle import NozzleModel
    from cellctl.washing.plan import WashParams, plan_wash

    cfg = opts.load_config()
    n = opts.n or 6
    nozzle = NozzleModel.from_config(cfg.nozzle)
    robot = default_robot_model()
    wc = cfg.wash
    params = WashParams(threshold=wc.threshold, margin_m=wc.margin_m, seed=opts.seed)
    # the reference: three times the rolls and no CPU budget on the residue pass
    generous = WashParams(
        threshold=wc.threshold, margin_m=wc.margin_m, seed=opts.seed, n_roll=12, cpu_budget_s=float("inf")
    )
    cat = load_catalog(cfg.path(cfg.catalog), cfg.root)
    wh = cfg.planner.whole
    sp = StationParams(
        candidates=wh.candidates,
        park_distance_m=wh.park_distance_m,
        max_stations=wh.max_stations,
        cabin_half_m=wh.cabin_half_m,
        bin_in_cabin=wh.bin_in_cabin,
        allowed_deg=tuple(wh.allowed_deg) if wh.allowed_deg is not None else None,
    )
    pics = Path(cfg.root) / "docs" / "washing" if opts.out is not None else None
    rng = np.random.default_rng(opts.seed)
    names = list(cat.names)
    meshes: dict[str, Any] = {}
    mixed: list[dict[str, Any]] = []
    washable: list[dict[str, Any]] = []
    run = {"nozzle": nozzle, "robot": robot, "params": params, "max_rounds": wc.max_rounds}
    for c in range(n):
        name = names[c % len(names)]
        if name not in meshes:
            bt = cat.get(name)
            mesh = read_bin_mesh(cat.mesh_path(name))
            st = [cd.T_bin_base for cd in candidate_stations(mesh, bt, sp) if cd.reason is None]
            meshes[name] = (mesh, st)
        mesh, stations = meshes[name]
        amount, pseed = float(rng.uniform(0.3, 1.0)), int(rng.integers(1 << 30))
        field = PowderField.sample(mesh, amount, pseed)
        ref = plan_wash(mesh, gt_dirt_map(field, mesh), stations, nozzle, robot, generous)
        reach = ref.covered.copy()
        head = {
            "cycle": c + 1,
            "bin_type": name,
            "powder_amount": round(amount, 3),
            "powder_seed": pseed,
            "reference_plan_s": round(ref.times_s.get("total", 0.0), 3),
        }
        only = washable_only(field, mesh, reach)  # before the mixed run washes the field
        shown = pics if c < PICTURE_CYCLES else None
        mixed.append(
            {**head, "clumps": len(field.radii), **_run_bin(mesh, stations, field, reach, run, shown, f"c{c + 1}")}
        )
        if only.dirty_faces(mesh).any():  # a bin whose every dirty face is out of reach has no washable twin
            rec = _run_bin(mesh, stations, only, reach, run, shown, f"w{c + 1}")
            washable.append({**head, "clumps": len(only.radii), **rec})
    return {
        "bench": "wash",
        "cycles": n,
        "seed": opts.seed,
        "dirt_source": "ground_truth: face_p = the twin powder's largest opacity at each face's centroid and corners "
        "(the detector is not run: see cellctl/bench/wash.py)",
        "nozzle": nozzle.to_json(),
        "wash": {"threshold": wc.threshold, "margin_m": wc.margin_m, "max_rounds": wc.max_rounds},
        "sets": {
            "washable": "top level: each seeded bin with only its clumps on faces a nozzle reaches from its stations "
            "(the reference plan's covered faces); bins_clean_fraction is the issue's target here",
            "mixed": "'mixed': the seeded bins as sampled, powder also where no nozzle pose reaches (they end dirty)",
        },
        **_summary(washable, wc.max_rounds),
        "mixed": _summary(mixed, wc.max_rounds),
        "stamp": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


def _run_bin(
    mesh: Any,
    stations: list[Any],
    field: Any,
    reach: np.ndarray,
    run: dict[str, Any],
    pics: Path | None,
    tag: str,
) -> dict[str, Any]:
    """Wash-and-verify rounds on one seeded bin (the twin's powder ``field`` is washed in place)."""
    from cellctl.washing.plan import plan_wash
    from cellctl.washing.twin import spray_passes

    nozzle, robot, params = run["nozzle"], run["robot"], run["params"]
    a = mesh.areas
    dirty0 = field.dirty_faces(mesh)
    reach = reach.copy()
    rounds: list[dict[str, Any]] = []
    covered0 = np.zeros(mesh.n_faces, bool)
    dirty = dirty0
    for r in range(run["max_rounds"]):
        dm = gt_dirt_map(field, mesh)
        plan = plan_wash(mesh, dm, stations, nozzle, robot, params)
        reach |= plan.covered
        if r == 0:
            covered0 = plan.covered.copy()
        passes = spray_passes(plan, mesh, nozzle)
        for s in passes:
            field.wash(s)
        after = field.dirty_faces(mesh)
        rounds.append(
            {
                "round": r + 1,
                "dirty_before_m2": round(float(a[dirty].sum()), 5),
                "dirty_after_m2": round(float(a[after].sum()), 5),
                "dirty_after_reachable_m2": round(float(a[after & reach].sum()), 5),
                "passes": len(passes),
                "plan": plan.summary(mesh),
            }
        )
        if pics is not None:
            _pictures(pics, tag, r, mesh, dm, plan, passes, field)
        dirty = after
        print(
            f"wash bench: {tag} round {r + 1}: dirty {a[dirty].sum():.4f} m² left, "
            f"plan {plan.times_s.get('total', 0):.1f} s wall {plan.cpu_s:.1f} s cpu",
            file=sys.stderr,
        )
        if not (dirty & reach).any() or not plan.moves:
            break
    reachable_dirty0 = dirty0 & reach
    rd = float(a[reachable_dirty0].sum())
    clean_reachable = not (dirty & reach).any()
    return {
        "stations_available": len(stations),
        "dirty_m2": round(float(a[dirty0].sum()), 5),
        "dirty_reachable_m2": round(rd, 5),
        "dirty_area_covered": round(float(a[reachable_dirty0 & covered0].sum()) / rd, 5) if rd > 0 else None,
        "all_dirt_reachable": bool(not (dirty0 & ~reach).any()),
        "verdict": "clean" if not dirty.any() else "dirty",
        "clean_on_reachable_faces": clean_reachable,
        "rounds": len(rounds),
        "rounds_to_clean_reachable": len(rounds) if clean_reachable else None,
        "remaining_dirty_m2": round(float(a[dirty].sum()), 5),
        "remaining_unwashable": rounds[-1]["plan"]["unwashable"][:10],
        "washed_m2": round(sum(x["plan"]["washed_m2"] for x in rounds), 5),
        "whole_bin_m2": round(float(a.sum()), 5),
        "plan_s": [x["plan"]["times_s"].get("total", 0.0) for x in rounds],
        "plan_cpu_s": [x["plan"]["cpu_s"] for x in rounds],
        "rounds_detail": rounds,
    }


def _summary(cycles: list[dict[str, Any]], max_rounds: int) -> dict[str, Any]:
    if not cycles:
        return {"bins": 0}
    n = len(cycles)
    cov = [c for c in cycles if c["dirty_area_covered"] is not None]
    reach_bins = [c for c in cycles if c["all_dirt_reachable"]]
    to_clean = [c["rounds_to_clean_reachable"] for c in cycles if c["rounds_to_clean_reachable"] is not None]
    plan_s = [s for c in cycles for s in c["plan_s"]]
    cpu_s = [s for c in cycles for s in c["plan_cpu_s"]]
    washed = sum(c["washed_m2"] for c in cycles)
    whole = sum(c["whole_bin_m2"] for c in cycles)
    covered = sum(c["dirty_area_covered"] * c["dirty_reachable_m2"] for c in cov)
    return {
        "bins": n,
        "dirty_area_covered": round(covered / max(1e-12, sum(c["dirty_reachable_m2"] for c in cov)), 5),
        "dirty_area_covered_min": round(min(c["dirty_area_covered"] for c in cov), 5) if cov else None,
        "dirty_area_reachable_share": round(
            sum(c["dirty_reachable_m2"] for c in cycles) / max(1e-12, sum(c["dirty_m2"] for c in cycles)), 5
        ),
        "bins_clean_fraction": round(sum(c["verdict"] == "clean" for c in cycles) / n, 4),
        "bins_clean_on_reachable_faces_fraction": round(sum(c["clean_on_reachable_faces"] for c in cycles) / n, 4),
        "bins_all_dirt_reachable": len(reach_bins),
        "bins_all_dirt_reachable_clean_fraction": (
            round(sum(c["verdict"] == "clean" for c in reach_bins) / len(reach_bins), 4) if reach_bins else None
        ),
        "rounds": {
            "median": statistics.median(to_clean) if to_clean else None,
            "max": max(to_clean) if to_clean else None,
            "runs": [c["rounds"] for c in cycles],
        },
        "rounds_max": max(c["rounds"] for c in cycles),
        "rounds_limit": max_rounds,
        "washed_m2": round(washed, 4),
        "whole_bin_wash_m2": round(whole, 4),
        "washed_vs_whole_bin": round(washed / whole, 4) if whole else None,
        "saving": round(1 - washed / whole, 4) if whole else None,
        "plan_s_max": round(max(plan_s), 3) if plan_s else None,
        "plan_s_median": round(statistics.median(plan_s), 3) if plan_s else None,
        "plan_cpu_s_max": round(max(cpu_s), 3) if cpu_s else None,
        "plan_s_note": "wall clock per round on the machine the bench ran on; cpu_s = this process's CPU time",
        "per_cycle": [{k: v for k, v in c.items() if k != "rounds_detail"} for c in cycles],
        "rounds_detail": [c["rounds_detail"] for c in cycles],
    }


def _pictures(
    folder: Path, tag: str, r: int, mesh: Any, dm: dict[str, Any], plan: Any, passes: list[Any], field: Any
) -> None:
    from cellctl.recording.dirt_map import draw_dirt_map
    from cellctl.washing.pictures import draw_wash_path

    stem = f"wash_{tag}_r{r + 1}"
    title = f"{tag} round {r + 1}"
    draw_dirt_map(mesh, dm, folder / f"{stem}_before.png", title=f"{title}: before")
    draw_wash_path(mesh, plan, passes, folder / f"{stem}_path.png", title=f"{title}:")
    draw_dirt_map(mesh, gt_dirt_map(field, mesh), folder / f"{stem}_after.png", title=f"{title}: after")
