"""``cellctl bench inspect --cycles N``: the bin-level verdict and the dirt map against ground truth.

N seeded sim cycles of the perception chain, in process (no bus: what is measured is the
decision, not the transport). Each cycle takes one surface (alternating external, internal)
and one contamination kind (cycling ``clean``, ``one_spot``, ``many_spots``):

* ``clean`` — no powder;
* ``one_spot`` — one clump of radius 1.2–2.5 cm on a random face the plan sees;
* ``many_spots`` — the twin's powder model (:class:`cellctl.sim.ground_truth.PowderField`,
  amount U(0.3, 1)), clumps on both surfaces.

The plan of each surface is made once (fast mode, p_SP 10 %, the sim's nominal parking pose).
Every planned viewpoint is rendered by the twin at 256×144 (the size of the twin training
renders; the detector squashes every frame to 128², so the full 1280×720 would cost ~25× the
render time for the same input) from the
planned pose jittered by ±1 cm / ±1° as a re-parked robot reaches it, with the cycle's
lighting; the ID board (and, for the surfaces of ``classifier.mask_cabin``, the cabin past the
bin) is masked exactly as the scanning step does; the detector decides; an
uncertain view is re-looked at from :func:`~cellctl.classify.heatmap.relook_pose` (up to
``classifier.relook.max_views`` per cycle); all views are fused per face
(:func:`~cellctl.classify.heatmap.fuse_views`) and the verdict follows
``classifier.verdict``.

Ground truth: a face is dirty when the powder field's opacity exceeds 0.5 at any point of the
barycentric grid of step 1/12 on it (91 points, ~0.5 cm apart on a median face:
:func:`_dirty_faces`); only faces the cycle's plan sees count. Until round 5 the truth was ten
points a face (corners, edge midpoints, centroid, three inner points: :func:`_dirty_faces_10pt`),
which misses clump edges and the halo grains the camera sees: the JSON reports the face
metrics against that truth too (``face_recall_10pt``, ``face_precision_10pt``). A bin
is *dirty-seen* when a seen face is dirty — the bins whose false-clean rate must be 0; a
contaminated bin whose powder lies only on unseen faces is reported apart. Face precision and
recall are area-weighted over all cycles.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cellctl.bench.options import BenchOptions
from cellctl.images import MAX_IMAGE_PIXELS
from cellctl.surface import Surface

__all__ = ["KINDS", "bench_inspect", "classifier_view", "collect_cycles", "score_cycles"]

KINDS = ("clean", "one_spot", "many_spots")
BENCH_BIN = "case_study"
RENDER_WIDTH = 256


def point_on_face(mesh: Any, faces: np.ndarray, rng: np.random.Generator) -> tuple[int, np.ndarray]:
    """A face drawn from ``faces`` and a uniform point on it (bin frame)."""
    f = int(rng.choice(faces))
    tri = mesh.vertices[mesh.faces[f]]
    u, v = rng.uniform(size=2)
    if u + v > 1:
        u, v = 1 - u, 1 - v
    return f, tri[0] + u * (tri[1] - tri[0]) + v * (tri[2] - tri[0])


def _one_spot(mesh: Any, seen_faces: np.ndarray, rng: np.random.Generator, seed: int) -> Any:
    from cellctl.sim.ground_truth import PowderField

    f, c = point_on_face(mesh, seen_faces, rng)
    return PowderField(
        c[None, :],
        np.array([float(rng.uniform(0.012, 0.025))]),
        np.array([mesh.surface[f]], np.uint8),
        mesh.normals[f][None, :],
        seed,
    )


TRUTH_GRID = 12
"""Barycentric grid step 1/TRUTH_GRID of the truth's sample points per face ((k+1)(k+2)/2 = 91)."""


def _dirty_faces(field: Any, mesh: Any, threshold: float = 0.5, k: int = TRUTH_GRID) -> np.ndarray:
    """Faces (F,) where the powder opacity exceeds ``threshold`` at any point of the barycentric
    grid of step 1/``k`` (corners and edges included)."""
    if len(field.radii) == 0:
        return np.zeros(mesh.n_faces, bool)
    w = np.array([(a, b, k - a - b) for a in range(k + 1) for b in range(k + 1 - a)], np.float64) / k
    tri = mesh.vertices[mesh.faces]
    pts = np.einsum("sk,fkd->sfd", w, tri).reshape(-1, 3)
    n = len(w)
    a = field.alpha(pts, np.tile(mesh.surface, n), np.tile(mesh.normals, (n, 1))).reshape(n, -1)
    return (a > threshold).any(axis=0)


def _dirty_faces_10pt(field: Any, mesh: Any, threshold: float = 0.5) -> np.ndarray:
    """Faces (F,) where the powder opacity exceeds ``threshold`` at any of 10 sample points
    (corners, edge midpoints, centroid, centroid-corner midpoints). ``PowderField.dirty_faces``
    tests centroid and corners only, which misses a 1–2 cm spot inside a large triangle."""
    tri = mesh.vertices[mesh.faces]
    c = tri.mean(axis=1)
    pts = [
        tri[:, 0],
        tri[:, 1],
        tri[:, 2],
        (tri[:, 0] + tri[:, 1]) / 2,
        (tri[:, 1] + tri[:, 2]) / 2,
        (tri[:, 2] + tri[:, 0]) / 2,
        c,
        (c + tri[:, 0]) / 2,
        (c + tri[:, 1]) / 2,
        (c + tri[:, 2]) / 2,
    ]
    k = len(pts)
    a = field.alpha(np.concatenate(pts), np.tile(mesh.surface, k), np.tile(mesh.normals, (k, 1))).reshape(k, -1)
    return (a > threshold).any(axis=0)


def classifier_view(
    png: bytes,
    cabin: bool,
    bt: Any,
    mesh: Any,
    T_base_bin: np.ndarray,
    T_base_cam: np.ndarray,
    intr: Any,
    max_pixels: int = MAX_IMAGE_PIXELS,
) -> bytes:
    """What the scanning step hands the classifier for a view
    (:func:`cellctl.supervisor.steps.scanning.classifier_input`): the board filled in where its face
    is seen, and with ``cabin`` (the surface is in ``classifier.mask_cabin``) the cabin past the bin."""
    from cellctl.supervisor.steps.board_mask import mask_board
    from cellctl.supervisor.steps.scanning import mask_cabin

    png = mask_board(png, bt, T_base_bin, T_base_cam, intr, max_pixels)
    return mask_cabin(png, mesh, T_base_bin, T_base_cam, intr, max_pixels) if cabin else png


def bench_inspect(opts: BenchOptions) -> dict[str, Any]:
    """Run ``opts.n`` cycles (default 200); returns the JSON described in the module doc. (``--commissioned``:
    :mod:`cellctl.bench.classify.inspect_commissioned`.)"""
    cfg = opts.load_config()
    run = collect_cycles(opts, cfg)
    return score_cycles(run, cfg.classifier.verdict, figures_out=opts.out)


@dataclass
class _Scene:
    """What every cycle of the bench shares: the detectors, the bin and its plans, the render camera."""

    cfg: Any
    dets: dict[str, Any]
    bt: Any
    mesh: Any
    T_base_bin: np.ndarray
    render_cam: Any
    intr: Any
    plans: dict[Surface, Any]
    renderer: Any


@dataclass
class _Draw:
    """One cycle's seeded draw: surface, contamination kind, powder field and its truth, lighting."""

    rng: np.random.Generator
    surface: Surface
    kind: str
    seen_plan: np.ndarray
    pseed: int
    powder: Any
    gt: np.ndarray
    gt10: np.ndarray
    rp: Any
    T_world_bin: np.ndarray


@dataclass
class _Shots:
    """What the cycle's views leave behind: detector latencies (ms, all cycles), (hottest heat, image,
    heat map) per view, and the classifier's PNGs when the caller keeps them."""

    lat: list[float]
    keep_images: bool
    shots: list[tuple[float, np.ndarray, np.ndarray]] = field(default_factory=list)
    pngs: list[bytes] = field(default_factory=list)


def collect_cycles(opts: BenchOptions, cfg: Any = None, first: int = 0, keep_images: bool = False) -> dict[str, Any]:
    """The detector's side of the bench: every cycle's views (:class:`ViewEvidence`), labels,
    re-looks and ground truth, before any fusion. :func:`score_cycles` fuses and scores them, so
    that the fusion and the verdict rule can be compared on the same views (a validation bench
    with other seeds) without rendering or classifying again.

    Stages: :func:`_scene` (detectors, bin, plans) once; per cycle :func:`_draw` (the seeded
    contamination and lighting), :func:`_scan` (planned views, then re-looks at uncertain ones) and
    :func:`_cycle_record`.

    Args:
        first: first cycle index (cycles ``first..n-1``): each cycle draws from its own
            ``(seed, index)`` stream, so runs over consecutive ranges concatenate to one run.
    """
    import torch

    torch.set_num_threads(1)  # 2 shared cores: more threads only contend (measured 9 vs 500 ms)
    cfg = cfg if cfg is not None else opts.load_config()
    n = opts.n or 200
    scene = _scene(opts, cfg)
    lat: list[float] = []
    cycles: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    for i in range(first, n):
        draw = _draw(scene, opts.seed, i)
        shots = _Shots(lat, keep_images)
        views, labels, uncertain, relooks = _scan(scene, draw, shots)
        cycles.append(_cycle_record(draw, shots, views, labels, uncertain, relooks))
        if (i + 1) % 10 == 0:
            print(f"bench inspect: {i + 1}/{n} cycles, {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return {
        "cycles": cycles,
        "mesh": scene.mesh,
        "bin_type": scene.bt,
        "intrinsics": scene.intr,
        "latency_ms": lat,
        "relook": cfg.classifier.relook.model_dump(),
        "setup": _setup_record(scene, opts.seed, t0),
    }


def _scene(opts: BenchOptions, cfg: Any) -> _Scene:
    """Load both detectors (refused without them), the bench bin at the sim's nominal parking pose,
    the render camera, and plan each surface once (fast mode, p_SP 10 %)."""
    from cellctl.classify.fusion import load_detectors
    from cellctl.geometry.camera import CameraModel
    from cellctl.geometry.catalog import load_catalog
    from cellctl.planning.pipeline import PlanParams, make_plan
    from cellctl.planning.robot import default_robot_model
    from cellctl.sim.render import SimRenderer
    from cellctl.sim.scene import nominal_T_bin_base
    from cellctl.surface import SURFACES

    dets, problems = load_detectors(cfg.path(cfg.classifier.models_dir))
    if problems:
        from cellctl.errors import ClassifierError

        raise ClassifierError(f"bench inspect needs both detectors: {problems}")
    catalog = load_catalog(cfg.path(cfg.catalog), cfg.root)
    bt = catalog.get(BENCH_BIN)
    mesh = catalog.load_mesh(BENCH_BIN)
    T_bin_base = nominal_T_bin_base(bt, mesh)
    cam = CameraModel.from_config(cfg.camera)
    render_cam = cam.scaled(RENDER_WIDTH / cam.width)
    robot = default_robot_model()
    plans = {}
    for s in SURFACES:
        print(f"bench inspect: planning {s}", file=sys.stderr)
        plan = make_plan(
            mesh, T_bin_base, PlanParams(surface=s, seed_pct=10, mode="fast", seed=opts.seed), robot, bin_type=BENCH_BIN
        )
        plans[s] = plan
    return _Scene(
        cfg, dets, bt, mesh, np.linalg.inv(T_bin_base), render_cam, render_cam.intrinsics(), plans, SimRenderer(catalog)
    )


def _draw(scene: _Scene, seed: int, i: int) -> _Draw:
    """Cycle ``i``'s surface and kind (alternating, cycling), its powder field, truth and lighting, from
    its own ``(seed, i)`` stream; the stream then jitters the cycle's viewpoints (:func:`_scan`)."""
    from cellctl.sim.ground_truth import PowderField
    from cellctl.sim.render import RenderParams
    from cellctl.sim.scene import Scenario
    from cellctl.surface import SURFACES

    mesh = scene.mesh
    rng = np.random.default_rng([seed, i, 4711])
    surface = SURFACES[i % 2]
    kind = KINDS[(i // 2) % 3]
    plan = scene.plans[surface]
    seen_plan = np.unique(np.concatenate([np.asarray(vp.faces, np.int64) for vp in plan.viewpoints]))
    pseed = int(rng.integers(2**31))
    if kind == "clean":
        powder = PowderField.sample(mesh, 0.0, pseed)
    elif kind == "one_spot":
        powder = _one_spot(mesh, seen_plan, rng, pseed)
    else:
        powder = PowderField.sample(mesh, float(rng.uniform(0.3, 1.0)), pseed)
    gt = _dirty_faces(powder, mesh) if len(powder.radii) else np.zeros(mesh.n_faces, bool)
    gt10 = _dirty_faces_10pt(powder, mesh) if len(powder.radii) else np.zeros(mesh.n_faces, bool)
    rp = RenderParams(
        exposure=float(rng.uniform(0.8, 1.2)),
        light_scale=float(rng.uniform(0.8, 1.2)),
        light_offset=tuple(float(v) for v in rng.uniform(-0.3, 0.3, 3)),
        noise_sigma=float(rng.uniform(1.0, 3.0)),
    )
    T_world_bin = Scenario(bin_type=BENCH_BIN).T_world_bin(scene.bt)
    return _Draw(rng, surface, kind, seen_plan, pseed, powder, gt, gt10, rp, T_world_bin)


def _look(scene: _Scene, draw: _Draw, shots: _Shots, T_bin_cam: np.ndarray, k: int) -> Any:
    """Render view ``k`` of the cycle from ``T_bin_cam``, mask it as the scanning step does, and let the
    surface's detector decide (timed)."""
    from cellctl.images import decode_image, encode_image

    cfg = scene.cfg
    # the renderer's private entry point takes a PowderField directly: the one-spot
    # field is not one of its seeded scenarios
    out = scene.renderer._render(
        BENCH_BIN,
        draw.T_world_bin,
        None,
        None,
        draw.T_world_bin @ T_bin_cam,
        scene.render_cam,
        draw.rp,
        draw.pseed + k,
        draw.powder,
        True,
    )
    png = classifier_view(
        encode_image(out.rgb, "png"),
        draw.surface in cfg.classifier.mask_cabin,
        scene.bt,
        scene.mesh,
        scene.T_base_bin,
        scene.T_base_bin @ T_bin_cam,
        scene.intr,
        cfg.camera.max_image_pixels,
    )
    img = decode_image(png, "bench view", max_pixels=cfg.camera.max_image_pixels)
    t = time.perf_counter()
    d = scene.dets[draw.surface].predict([img])[0]
    shots.lat.append((time.perf_counter() - t) * 1000)
    shots.shots.append((float(d.heat.max()), img, d.heat))
    if shots.keep_images:
        shots.pngs.append(png)
    return d


def _scan(scene: _Scene, draw: _Draw, shots: _Shots) -> tuple[list[Any], list[str], int, int]:
    """Every planned view (jittered ±1 cm as a re-parked robot reaches it), then re-looks at the uncertain
    ones, least certain first, up to ``classifier.relook.max_views``: (views, labels, uncertain, relooks)."""
    from cellctl.classify.heatmap import ViewEvidence, relook_pose

    rc = scene.cfg.classifier.relook
    views: list[Any] = []
    labels: list[str] = []
    uncertain = 0
    relooks = 0
    pending = []
    for vp in scene.plans[draw.surface].viewpoints:
        T = np.asarray(vp.T_bin_cam, np.float64).copy()
        T[:3, 3] += draw.rng.uniform(-0.01, 0.01, 3)
        d = _look(scene, draw, shots, T, len(views))
        views.append(ViewEvidence(np.asarray(vp.faces, np.int64), T, d.heat, d.p_dirty))
        labels.append(d.label)
        if d.uncertain:
            uncertain += 1
            pending.append((abs(float(np.log(d.p_dirty / (1 - d.p_dirty + 1e-9) + 1e-9))), T, vp))
    pending.sort(key=lambda x: x[0])
    k = 0
    while pending and relooks < rc.max_views:
        _, T, vp = pending.pop(0)
        T2 = relook_pose(T, k, rc.offset_m, rc.glance_deg, rc.depth_m)
        k += 1
        relooks += 1
        d = _look(scene, draw, shots, T2, len(views))
        views.append(ViewEvidence(np.asarray(vp.faces, np.int64), T2, d.heat, d.p_dirty))
        labels.append(d.label)
        if d.uncertain:
            pending.append((0.0, T2, vp))
    return views, labels, uncertain, relooks


def _cycle_record(
    draw: _Draw, shots: _Shots, views: list[Any], labels: list[str], uncertain: int, relooks: int
) -> dict[str, Any]:
    """One cycle of :func:`collect_cycles`'s ``cycles`` (what :func:`score_cycles` reads)."""
    hot = max(shots.shots, key=lambda x: x[0])
    return {
        "surface": draw.surface,
        "kind": draw.kind,
        "gt": draw.gt,
        "gt10": draw.gt10,
        "seen_plan": draw.seen_plan,
        "views": views,
        "labels": labels,
        "uncertain": uncertain,
        "relooks": relooks,
        # the figures need only the hottest view of a many-spot cycle
        "hottest": (hot[1], hot[2]) if draw.kind == "many_spots" else None,
        **({"images": shots.pngs} if shots.keep_images else {}),
    }


def _setup_record(scene: _Scene, seed: int, t0: float) -> dict[str, Any]:
    """The run's ``setup``: bin, seed, render size, masks, plans, models, wall time, load."""
    return {
        "bin": BENCH_BIN,
        "seed": seed,
        "render_px": [scene.intr.width, scene.intr.height],
        "mask_cabin": list(scene.cfg.classifier.mask_cabin),
        "plans": {
            s: {"viewpoints": len(p.viewpoints), "coverage": round(float(p.coverage), 4)}
            for s, p in scene.plans.items()
        },
        "models": {s: d.model_id for s, d in scene.dets.items()},
        "seconds": round(time.perf_counter() - t0, 1),
        "loadavg_1m": round(os.getloadavg()[0], 2),
        "torch_threads": 1,
    }


def score_cycles(run: dict[str, Any], vc: Any, figures_out: Any = None) -> dict[str, Any]:
    """Fuse each collected cycle's views per face, take the verdict ``vc`` (a
    :class:`~cellctl.config.VerdictConfig`) and score bins and faces against the truth."""
    from cellctl.classify.heatmap import fuse_config, verdict
    from cellctl.surface import SURFACES

    mesh, intr = run["mesh"], run["intrinsics"]
    figures: dict[str, list[str]] = {}
    tot = {k: 0.0 for k in ("tp", "fp", "fn", "tp10", "fp10", "fn10")}
    bins: list[dict[str, Any]] = []
    for i, c in enumerate(run["cycles"]):
        surface, kind, gt, labels = c["surface"], c["kind"], c["gt"], c["labels"]
        fm = fuse_config(c["views"], mesh, intr, vc, run.get("bin_type"))
        v_faces = verdict(fm, labels, vc.rule, vc.min_dirty_area_cm2)
        v_views = verdict(fm, labels, "views")
        seen = np.zeros(mesh.n_faces, bool)
        seen[c["seen_plan"]] = True
        on = mesh.surface == (0 if surface == "external" else 1)
        gt_seen = gt & seen
        pred = fm.dirty & seen
        a = mesh.areas
        tot["tp"] += float(a[pred & gt_seen].sum())
        tot["fp"] += float(a[pred & ~gt_seen].sum())
        tot["fn"] += float(a[gt_seen & ~pred].sum())
        gt10_seen = c.get("gt10", gt) & seen
        tot["tp10"] += float(a[pred & gt10_seen].sum())
        tot["fp10"] += float(a[pred & ~gt10_seen].sum())
        tot["fn10"] += float(a[gt10_seen & ~pred].sum())
        bins.append(
            {
                "surface": surface,
                "kind": kind,
                "dirty_seen": bool(gt_seen.any()),
                "dirty_unseen_only": bool(gt.any() and not gt_seen.any()),
                "verdict": v_faces,
                "verdict_any_view": v_views,
                "uncertain": c["uncertain"],
                "relooks": c["relooks"],
                "views": len(c["views"]),
                "gt_dirty_area_cm2": round(float(a[gt_seen].sum()) * 1e4, 2),
                "pred_dirty_area_cm2": round(float(a[pred].sum()) * 1e4, 2),
                "gt_faces_on_surface": int((gt_seen & on).sum()),
            }
        )
        if figures_out is not None and kind == "many_spots" and surface not in figures and c["hottest"] is not None:
            figures[surface] = _figures(figures_out, surface, i, mesh, fm, gt_seen, c["hottest"])

    def rates(key: str) -> dict[str, Any]:
        dirty = [b for b in bins if b["dirty_seen"]]
        clean = [b for b in bins if not b["dirty_seen"] and not b["dirty_unseen_only"]]
        fc = sum(b[key] == "clean" for b in dirty)
        fd = sum(b[key] == "dirty" for b in clean)
        return {
            "bin_false_clean_rate": round(fc / len(dirty), 5) if dirty else None,
            "bin_false_dirty_rate": round(fd / len(clean), 5) if clean else None,
            "false_clean_bins": fc,
            "false_dirty_bins": fd,
            "dirty_seen_bins": len(dirty),
            "clean_bins": len(clean),
        }

    per: dict[str, Any] = {}
    for s in SURFACES:
        for kind in KINDS:
            sel = [b for b in bins if b["surface"] == s and b["kind"] == kind]
            if sel:
                per[f"{s}/{kind}"] = {
                    "cycles": len(sel),
                    "verdict_dirty": sum(b["verdict"] == "dirty" for b in sel),
                    "dirty_seen": sum(b["dirty_seen"] for b in sel),
                    "uncertain_views": sum(b["uncertain"] for b in sel),
                    "relooks": sum(b["relooks"] for b in sel),
                }
    lat_a = np.array(run["latency_ms"])
    main = rates("verdict")
    return {
        **main,
        "face_recall": round(tot["tp"] / (tot["tp"] + tot["fn"]), 5) if tot["tp"] + tot["fn"] > 0 else None,
        "face_precision": round(tot["tp"] / (tot["tp"] + tot["fp"]), 5) if tot["tp"] + tot["fp"] > 0 else None,
        "face_metrics": "area-weighted over all cycles, faces the cycle's plan sees; truth = powder opacity > 0.5 "
        f"at any of the {(TRUTH_GRID + 1) * (TRUTH_GRID + 2) // 2} points of the face's barycentric grid",
        "face_recall_10pt": _ratio(tot["tp10"], tot["tp10"] + tot["fn10"]),
        "face_precision_10pt": _ratio(tot["tp10"], tot["tp10"] + tot["fp10"]),
        "cycles": len(run["cycles"]),
        "uncertain_views": int(sum(b["uncertain"] for b in bins)),
        "relooks": int(sum(b["relooks"] for b in bins)),
        "views": int(sum(b["views"] for b in bins)),
        "dirty_unseen_only_bins": int(sum(b["dirty_unseen_only"] for b in bins)),
        "per_image_ms_p50": round(float(np.percentile(lat_a, 50)), 2) if len(lat_a) else None,
        "per_image_ms_p95": round(float(np.percentile(lat_a, 95)), 2) if len(lat_a) else None,
        "any_view_rule": rates("verdict_any_view"),
        "per_surface_kind": per,
        "verdict_rule": vc.model_dump(),
        "relook": run["relook"],
        "setup": run["setup"],
        "figures": figures,
    }


def _ratio(a: float, b: float) -> float | None:
    return round(a / b, 5) if b > 0 else None


def _figures(out: Any, surface: str, cycle: int, mesh: Any, fm: Any, gt_seen: np.ndarray, hottest: tuple) -> list[str]:
    """Beside the JSON: the cycle's dirt map (fused probabilities), the truth, and its hottest view
    with its heat map."""
    from pathlib import Path

    import cv2

    from cellctl.classify.heatmap import heat_png
    from cellctl.recording.dirt_map import draw_dirt_map

    base = Path(out)
    stem = base.with_suffix("").name
    paths = []
    dm = fm.as_json()
    p = draw_dirt_map(mesh, dm, base.with_name(f"{stem}_dirtmap_{surface}.png"), title=f"cycle {cycle} {surface}")
    paths.append(p.name)
    truth = {"seen_dirty": np.flatnonzero(gt_seen).tolist(), "seen_clean": []}
    p = draw_dirt_map(mesh, truth, base.with_name(f"{stem}_truth_{surface}.png"), title=f"cycle {cycle} truth")
    paths.append(p.name)
    img, heat = hottest
    h, w = img.shape[:2]
    hm = cv2.imdecode(np.frombuffer(heat_png(heat, w, h), np.uint8), cv2.IMREAD_COLOR)
    pair = np.hstack([cv2.cvtColor(img, cv2.COLOR_RGB2BGR), hm])
    q = base.with_name(f"{stem}_heat_{surface}.png")
    cv2.imwrite(str(q), cv2.resize(pair, (pair.shape[1] * 2, pair.shape[0] * 2), interpolation=cv2.INTER_NEAREST))
    paths.append(q.name)
    return paths
