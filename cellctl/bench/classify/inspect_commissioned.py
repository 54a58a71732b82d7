"""``cellctl bench inspect --commissioned``: the bin verdict with and without commissioned references.

One commissioning cycle per bin type (the bench's one bin, both surfaces' plans): every planned
viewpoint of the clean bin is rendered and stored as its reference, the camera pose and the viewed
plane as the scan stores and the worker uses them (:mod:`cellctl.supervisor.steps.references`,
:mod:`cellctl.workers.classifier.referencing`). Then N seeded cycles; each view is decided twice
from the same image — by the shipped detector alone and by
:func:`cellctl.classify.reference.decide` against the view's reference (the shipped fusion) — and
each arm re-looks its own uncertain views (``classifier.relook``; a re-look has no reference), fuses
its views per face and takes the verdict (``classifier.verdict``), scored as
:mod:`cellctl.bench.classify.inspect` scores (area-weighted faces, bins whose dirt lies on faces the
plan sees).

**Poses.** The bin is parked with the demo's error (10 mm in a random horizontal direction, ±0.5°
yaw) in every cycle, the commissioning one too; the plan is adjusted to the *measured* bin pose, so
the camera reaches the planned pose in the measured bin frame. The measurement's error is what
moves the camera against the bin between cycles: a rigid error of the bin frame of up to
:data:`BIN_POSE_ERROR` (uniform magnitude, random axis; ``docs/figures/bench_pose.json``: the
board's bin-origin error at 1 m is 0.6 mm p50 / 2.3 mm p95, rotation 0.06° / 0.3°). The cell sees
only measured poses, so the comparison's prior says "no motion" and ECC must find the rest.

**Appearance.** Exposure, light level and sensor noise vary per cycle as in ``bench inspect``; the cabin's
lights stay where they were at commissioning (:data:`CELL_LIGHTS`).

**Contamination** cycles through ``clean``, ``one_spot`` (one powder clump on a seen face),
``many_spots`` (the twin's powder field) and ``family``: one decal of a training family other than
powder (:data:`DECAL_FAMILIES`: film, streak, droplet, fibre, fingerprint, soot, tarnish) laid on a
seen wall — drawn once in the wall's plane and composited into every view through the ray cast of
each pixel, so all views of the cycle see the same dirt (:class:`Decal`). Truth of a decal face:
the decal's opacity ≥ :data:`DECAL_TRUTH_ALPHA` at a point of the face's barycentric grid.

**Slices.** Cycle ``i`` draws from its own ``(seed, i)`` stream and the commissioning from ``seed``
alone, so ``--seed-offset K --cycles 50`` runs cycles K..K+49 of the same run; the JSON keeps
every bin's record and :func:`merge` concatenates slices into the figures of the whole run.
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cellctl.bench.classify.inspect import (
    BENCH_BIN,
    RENDER_WIDTH,
    TRUTH_GRID,
    _dirty_faces,
    _one_spot,
    classifier_view,
    point_on_face,
)
from cellctl.bench.classify.pairs import BIN_POSE_ERROR, rigid_error
from cellctl.bench.options import BenchOptions

__all__ = [
    "ARMS",
    "BIN_POSE_ERROR",
    "DECAL_FAMILIES",
    "KINDS",
    "PARKING_ERROR",
    "Decal",
    "bench_commissioned",
    "bench_inspect_commissioned",
    "merge",
    "summarise",
]

KINDS = ("clean", "one_spot", "many_spots", "family")
DECAL_FAMILIES = ("film", "streak", "droplet", "fibre", "fingerprint", "soot", "tarnish")
PARKING_ERROR = (10.0, 0.5)
"""mm (horizontal, random direction) and degrees (yaw, random sign) the bin is parked off, every cycle."""
ARMS = ("references", "detector")
CELL_LIGHTS = (0.0, 0.0, 0.0)
"""Light offset (m) of every render: the cabin's lights are part of the cell and do not move between the
commissioning and a cycle (the reference pairs the fusion was fitted on keep them too). ``bench inspect``
moves them ±0.3 m per cycle to stress the detector; against references that is a different cell each cycle
(at commit 4cd85ab, which moved them, the fused arm called 6 of 14 clean bins dirty, the detector 0)."""
DECAL_TRUTH_ALPHA = 0.3
"""Decal opacity from which a face counts as dirty: the thinnest film the family draws (0.3–0.65); the
powder's 0.5 would call most films clean."""
DECAL_PX = 64
"""Texture side of a decal: about the decal's size in a 256 px render, the scale the families are drawn at."""


@dataclass(frozen=True)
class Decal:
    """A family layer lying in a wall's plane (bin frame): centre, unit normal, in-plane axes, side (m)."""

    layer: Any
    centre: np.ndarray
    normal: np.ndarray
    u: np.ndarray
    v: np.ndarray
    size_m: float

    def lookup(self, pts: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points (n, 3) with their face normals → (inside, alpha, rgb) of the decal there."""
        d = pts - self.centre
        on = (normals @ self.normal > 0.98) & (np.abs(d @ self.normal) < 0.003)
        x = (d @ self.u / self.size_m + 0.5) * DECAL_PX - 0.5
        y = (d @ self.v / self.size_m + 0.5) * DECAL_PX - 0.5
        inside = on & (x >= -0.5) & (x < DECAL_PX - 0.5) & (y >= -0.5) & (y < DECAL_PX - 0.5)
        alpha = _bilinear(self.layer.alpha, x, y) * inside
        rgb = _bilinear(self.layer.rgb, x, y)
        return inside, alpha.astype(np.float32), rgb.astype(np.float32)


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``img`` (H, W[, C]) at pixel coordinates ``x, y`` (n,), edges clamped."""
    h, w = img.shape[:2]
    x, y = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
    x0, y0 = np.minimum(x.astype(np.int64), w - 2), np.minimum(y.astype(np.int64), h - 2)
    fx, fy = x - x0, y - y0
    if img.ndim == 3:
        fx, fy = fx[:, None], fy[:, None]
    top = img[y0, x0] * (1 - fx) + img[y0, x0 + 1] * fx
    bottom = img[y0 + 1, x0] * (1 - fx) + img[y0 + 1, x0 + 1] * fx
    return (top * (1 - fy) + bottom * fy).astype(np.float32)


def _decal(mesh: Any, faces: np.ndarray, family: str, rng: np.random.Generator) -> Decal:
    from cellctl.classify.contamination import draw_family

    f, c = point_on_face(mesh, faces, rng)
    n = np.asarray(mesh.normals[f], np.float64)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    t = float(rng.uniform(0, 2 * np.pi))
    u, w = np.cos(t) * u + np.sin(t) * w, -np.sin(t) * u + np.cos(t) * w
    layer = draw_family(family, DECAL_PX, DECAL_PX, rng)
    return Decal(layer, c, n, u, w, float(rng.uniform(0.08, 0.15)))


def _decal_faces(decal: Decal, mesh: Any, k: int = TRUTH_GRID) -> np.ndarray:
    """Faces (F,) where the decal's opacity is ≥ :data:`DECAL_TRUTH_ALPHA` at a point of the barycentric grid."""
    w = np.array([(a, b, k - a - b) for a in range(k + 1) for b in range(k + 1 - a)], np.float64) / k
    tri = mesh.vertices[mesh.faces]
    pts = np.einsum("sk,fkd->sfd", w, tri).reshape(-1, 3)
    _, alpha, _ = decal.lookup(pts, np.tile(mesh.normals, (len(w), 1)))
    return (alpha.reshape(len(w), -1) >= DECAL_TRUTH_ALPHA).any(axis=0)


def _apply_decal(
    rgb: np.ndarray, decal: Decal, caster: Any, mesh: Any, T_bin_cam: np.ndarray, K: np.ndarray
) -> np.ndarray:
    """The render with the decal composited where a pixel's first hit lies on it."""
    from cellctl.classify.contamination import Layer, composite

    h, w = rgb.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w]
    d = np.c_[xs.ravel(), ys.ravel(), np.ones(h * w)] @ np.linalg.inv(K).T @ T_bin_cam[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    face, bary = caster.cast(np.broadcast_to(T_bin_cam[:3, 3], d.shape).copy(), d)
    hit = face >= 0
    if not hit.any():
        return rgb
    tri = mesh.vertices[mesh.faces[face[hit]]]
    bu, bv = bary[hit, 0:1].astype(np.float64), bary[hit, 1:2].astype(np.float64)
    pts = (1 - bu - bv) * tri[:, 0] + bu * tri[:, 1] + bv * tri[:, 2]
    inside, alpha, col = decal.lookup(pts, mesh.normals[face[hit]])
    if not inside.any():
        return rgb
    a_img = np.zeros(h * w, np.float32)
    c_img = np.zeros((h * w, 3), np.float32)
    a_img[np.flatnonzero(hit)] = alpha
    c_img[np.flatnonzero(hit)] = col
    layer = Layer(a_img.reshape(h, w), c_img.reshape(h, w, 3), decal.layer.mode, decal.layer.family, {})
    out, _ = composite(rgb.astype(np.float32) / 255.0, layer)
    return np.clip(out * 255 + 0.5, 0, 255).astype(np.uint8)


class _Scene:
    """The bench's bin, plans, renderer and models (built once per run)."""

    def __init__(self, opts: BenchOptions, cfg: Any) -> None:
        from cellctl.classify.fusion import load_detectors
        from cellctl.classify.heatmap import MeshCaster
        from cellctl.classify.reference import ReferenceFusion, fusion_path
        from cellctl.errors import ClassifierError
        from cellctl.geometry.camera import CameraModel
        from cellctl.geometry.catalog import load_catalog
        from cellctl.planning.pipeline import PlanParams, make_plan
        from cellctl.planning.robot import default_robot_model
        from cellctl.sim.render import SimRenderer
        from cellctl.sim.scene import Scenario, nominal_T_bin_base
        from cellctl.surface import SURFACES

        self.cfg = cfg
        models = cfg.path(cfg.classifier.models_dir)
        self.dets, problems = load_detectors(models)
        if problems:
            raise ClassifierError(f"bench inspect --commissioned needs both detectors: {problems}")
        self.fusions = {s: ReferenceFusion.load(fusion_path(models, s), s) for s in SURFACES}
        self.catalog = load_catalog(cfg.path(cfg.catalog), cfg.root)
        self.bt = self.catalog.get(BENCH_BIN)
        self.mesh = self.catalog.load_mesh(BENCH_BIN)
        T_bin_base = nominal_T_bin_base(self.bt, self.mesh)
        self.T_base_bin = np.linalg.inv(T_bin_base)
        cam = CameraModel.from_config(cfg.camera)
        self.render_cam = cam.scaled(RENDER_WIDTH / cam.width)
        self.intr = self.render_cam.intrinsics()
        self.K = self.intr.K()
        self.plans = {}
        for s in SURFACES:
            print(f"bench inspect --commissioned: planning {s}", file=sys.stderr)
            params = PlanParams(surface=s, seed_pct=10, mode="fast", seed=opts.seed)
            self.plans[s] = make_plan(self.mesh, T_bin_base, params, default_robot_model(), bin_type=BENCH_BIN)
        self.renderer = SimRenderer(self.catalog)
        self.caster = MeshCaster(self.mesh)
        self.T_world_bin0 = Scenario(bin_type=BENCH_BIN).T_world_bin(self.bt)

    def view(
        self,
        surface: str,
        T_world_bin: np.ndarray,
        E: np.ndarray,
        T_meas: np.ndarray,
        rp: Any,
        seed: int,
        field: Any,
        decal: Decal | None,
    ) -> np.ndarray:
        """The classifier's input (RGB) of a view planned at ``T_meas`` (measured bin frame); the camera truly
        is at ``E @ T_meas`` in the bin frame."""
        from cellctl.images import decode_image, encode_image

        T_true = E @ T_meas
        out = self.renderer._render(
            BENCH_BIN, T_world_bin, None, None, T_world_bin @ T_true, self.render_cam, rp, seed, field, True
        )
        rgb = out.rgb if decal is None else _apply_decal(out.rgb, decal, self.caster, self.mesh, T_true, self.K)
        png = classifier_view(
            encode_image(rgb, "png"),
            surface in self.cfg.classifier.mask_cabin,
            self.bt,
            self.mesh,
            self.T_base_bin,
            self.T_base_bin @ T_meas,
            self.intr,
            self.cfg.camera.max_image_pixels,
        )
        return decode_image(png, "bench view", max_pixels=self.cfg.camera.max_image_pixels)


def _render_params(rng: np.random.Generator) -> Any:
    """A cycle's appearance: exposure, light level and sensor noise vary as in ``bench inspect``; the lights
    stay where they are (:data:`CELL_LIGHTS`)."""
    from cellctl.sim.render import RenderParams

    e, ls = float(rng.uniform(0.8, 1.2)), float(rng.uniform(0.8, 1.2))
    rng.uniform(-0.3, 0.3, 3)  # the draw bench inspect spends on moving the lights: the streams stay aligned
    return RenderParams(exposure=e, light_scale=ls, light_offset=CELL_LIGHTS, noise_sigma=float(rng.uniform(1.0, 3.0)))


def commission(sc: _Scene, seed: int) -> dict[str, dict[int, Any]]:
    """The commissioning cycle: surface → viewpoint → :class:`~cellctl.classify.reference.ReferenceView`."""
    from cellctl.classify.reference import ReferenceView, plane_from_mesh
    from cellctl.sim.ground_truth import PowderField

    rng = np.random.default_rng([seed, 1789])
    T_world_bin = sc.T_world_bin0 @ rigid_error(rng, *PARKING_ERROR, uniform=False)
    E = rigid_error(rng, *BIN_POSE_ERROR, uniform=True)
    rp = _render_params(rng)
    clean = PowderField.sample(sc.mesh, 0.0, seed)
    refs: dict[str, dict[int, Any]] = {}
    for s, plan in sc.plans.items():
        refs[s] = {}
        for vp in plan.viewpoints:
            T = np.asarray(vp.T_bin_cam, np.float64)
            rgb = sc.view(s, T_world_bin, E, T, rp, seed + vp.index, clean, None)
            plane = plane_from_mesh(sc.caster, sc.mesh, T, sc.K, sc.intr.width, sc.intr.height)
            refs[s][vp.index] = ReferenceView(rgb, T, plane, sc.K)
    return refs


def _contamination(sc: _Scene, kind: str, i: int, seen: np.ndarray, surface: str, rng: np.random.Generator) -> tuple:
    """(powder field, decal or None, truth faces, family name or None) of cycle ``i``."""
    from cellctl.sim.ground_truth import PowderField

    pseed = int(rng.integers(2**31))
    decal = family = None
    if kind == "one_spot":
        field = _one_spot(sc.mesh, seen, rng, pseed)
    elif kind == "many_spots":
        field = PowderField.sample(sc.mesh, float(rng.uniform(0.3, 1.0)), pseed)
    else:
        field = PowderField.sample(sc.mesh, 0.0, pseed)
    gt = _dirty_faces(field, sc.mesh) if len(field.radii) else np.zeros(sc.mesh.n_faces, bool)
    if kind == "family":
        family = DECAL_FAMILIES[(i // 8) % len(DECAL_FAMILIES)]
        on = seen[sc.mesh.surface[seen] == (0 if surface == "external" else 1)]
        for _ in range(5):  # a family cycle is a dirty bin: redraw a decal too faint to count anywhere
            decal = _decal(sc.mesh, on if len(on) else seen, family, rng)
            faces = _decal_faces(decal, sc.mesh)
            if faces.any():
                break
        gt = gt | faces
    return field, decal, gt, family, pseed


def _cycle(sc: _Scene, refs: dict, opts: BenchOptions, i: int, lat: dict[str, list[float]]) -> dict[str, Any]:
    """One seeded cycle, both arms: the bins' records (:func:`_score`)."""
    from cellctl.classify.heatmap import ViewEvidence, relook_pose
    from cellctl.classify.reference import decide
    from cellctl.surface import SURFACES

    rng = np.random.default_rng([opts.seed, i, 4711])
    surface = SURFACES[i % 2]
    kind = KINDS[(i // 2) % len(KINDS)]
    plan = sc.plans[surface]
    det, fusion = sc.dets[surface], sc.fusions[surface]
    seen = np.unique(np.concatenate([np.asarray(vp.faces, np.int64) for vp in plan.viewpoints]))
    field, decal, gt, family, pseed = _contamination(sc, kind, i, seen, surface, rng)
    T_world_bin = sc.T_world_bin0 @ rigid_error(rng, *PARKING_ERROR, uniform=False)
    E = rigid_error(rng, *BIN_POSE_ERROR, uniform=True)
    rp = _render_params(rng)
    rc = sc.cfg.classifier.relook
    renders: dict[tuple, np.ndarray] = {}

    def look(T: np.ndarray, key: tuple) -> np.ndarray:
        if key not in renders:
            renders[key] = sc.view(surface, T_world_bin, E, T, rp, pseed + len(renders), field, decal)
        return renders[key]

    arms: dict[str, dict[str, Any]] = {a: {"views": [], "labels": [], "uncertain": 0, "paths": {}} for a in ARMS}
    pending: dict[str, list] = {a: [] for a in ARMS}
    for vp in plan.viewpoints:
        T = np.asarray(vp.T_bin_cam, np.float64)
        img = look(T, ("vp", vp.index))
        t = time.perf_counter()
        d = det.predict([img])[0]
        lat["detector"].append((time.perf_counter() - t) * 1000)
        t = time.perf_counter()
        r = decide(det, fusion, img, T, refs[surface].get(vp.index))
        lat["references"].append((time.perf_counter() - t) * 1000)
        faces = np.asarray(vp.faces, np.int64)
        for arm, (heat, p, label, unc) in (
            ("detector", (d.heat, d.p_dirty, d.label, d.uncertain)),
            ("references", (r.heat, r.p_dirty, r.label, r.uncertain)),
        ):
            a = arms[arm]
            a["views"].append(ViewEvidence(faces, T, heat, p))
            a["labels"].append(label)
            if unc:
                a["uncertain"] += 1
                pending[arm].append((abs(float(np.log(p / (1 - p + 1e-9) + 1e-9))), T, faces, vp.index))
        key = r.path if r.path == "reference" else f"detector:{r.reason}"
        arms["references"]["paths"][key] = arms["references"]["paths"].get(key, 0) + 1
    for arm in ARMS:  # each arm re-looks at its own uncertain views (no reference at a re-look pose)
        a, todo = arms[arm], sorted(pending[arm], key=lambda x: x[0])
        k = relooks = 0
        while todo and relooks < rc.max_views:
            _, T, faces, idx = todo.pop(0)
            T2 = relook_pose(T, k, rc.offset_m, rc.glance_deg, rc.depth_m)
            img = look(T2, ("relook", idx, k))
            k += 1
            relooks += 1
            d = det.predict([img])[0]
            a["views"].append(ViewEvidence(faces, T2, d.heat, d.p_dirty))
            a["labels"].append(d.label)
            if d.uncertain:
                todo.append((0.0, T2, faces, idx))
        a["relooks"] = relooks
    return {a: _score(sc, arms[a], surface, kind, family, gt, seen) for a in ARMS}


def _score(
    sc: _Scene, arm: dict, surface: str, kind: str, family: str | None, gt: np.ndarray, seen_faces: np.ndarray
) -> dict:
    from cellctl.classify.heatmap import fuse_config, verdict

    vc = sc.cfg.classifier.verdict
    fm = fuse_config(arm["views"], sc.mesh, sc.intr, vc, sc.bt)
    seen = np.zeros(sc.mesh.n_faces, bool)
    seen[seen_faces] = True
    gt_seen, pred, a = gt & seen, fm.dirty & seen, sc.mesh.areas
    return {
        "surface": surface,
        "kind": kind,
        "family": family,
        "dirty_seen": bool(gt_seen.any()),
        "dirty_unseen_only": bool(gt.any() and not gt_seen.any()),
        "verdict": verdict(fm, arm["labels"], vc.rule, vc.min_dirty_area_cm2),
        "uncertain": arm["uncertain"],
        "relooks": arm["relooks"],
        "views": len(arm["views"]),
        "tp_m2": float(a[pred & gt_seen].sum()),
        "fp_m2": float(a[pred & ~gt_seen].sum()),
        "fn_m2": float(a[gt_seen & ~pred].sum()),
        "paths": arm["paths"],
    }


def _pct(x: list[float], q: float) -> float | None:
    return round(float(np.percentile(x, q)), 2) if x else None


def summarise(bins: list[dict[str, Any]], latency_ms: list[float]) -> dict[str, Any]:
    """One arm's figures from its bins' records and per-view latencies."""
    dirty = [b for b in bins if b["dirty_seen"]]
    clean = [b for b in bins if not b["dirty_seen"] and not b["dirty_unseen_only"]]
    tp, fp, fn = (sum(b[k] for b in bins) for k in ("tp_m2", "fp_m2", "fn_m2"))
    fc = [b for b in dirty if b["verdict"] == "clean"]
    paths: dict[str, int] = {}
    for b in bins:
        for k, n in b["paths"].items():
            paths[k] = paths.get(k, 0) + n
    per: dict[str, Any] = {}
    for b in bins:
        key = f"{b['surface']}/{b['kind']}" + (f"/{b['family']}" if b["family"] else "")
        p = per.setdefault(key, {"cycles": 0, "dirty_seen": 0, "verdict_dirty": 0, "uncertain_views": 0})
        p["cycles"] += 1
        p["dirty_seen"] += b["dirty_seen"]
        p["verdict_dirty"] += b["verdict"] == "dirty"
        p["uncertain_views"] += b["uncertain"]
    unc_clean = [b["uncertain"] for b in clean]
    return {
        "bin_false_clean_rate": round(len(fc) / len(dirty), 5) if dirty else None,
        "bin_false_dirty_rate": round(sum(b["verdict"] == "dirty" for b in clean) / len(clean), 5) if clean else None,
        "false_clean_bins": len(fc),
        "false_clean_kinds": sorted({f"{b['surface']}/{b['kind']}/{b['family'] or '-'}" for b in fc}),
        "false_dirty_bins": sum(b["verdict"] == "dirty" for b in clean),
        "dirty_seen_bins": len(dirty),
        "clean_bins": len(clean),
        "dirty_unseen_only_bins": sum(b["dirty_unseen_only"] for b in bins),
        "face_recall": round(tp / (tp + fn), 5) if tp + fn > 0 else None,
        "face_precision": round(tp / (tp + fp), 5) if tp + fp > 0 else None,
        "uncertain_per_clean_cycle_median": float(np.median(unc_clean)) if unc_clean else None,
        "uncertain_per_clean_cycle_mean": round(float(np.mean(unc_clean)), 3) if unc_clean else None,
        "uncertain_views": sum(b["uncertain"] for b in bins),
        "relooks": sum(b["relooks"] for b in bins),
        "views": sum(b["views"] for b in bins),
        "per_view_ms_p50": _pct(latency_ms, 50),
        "per_view_ms_p95": _pct(latency_ms, 95),
        "view_paths": paths,
        "per_surface_kind": dict(sorted(per.items())),
    }


TARGETS = {
    "bin_false_clean_rate": "0 on bins whose dirt lies on faces the cycle saw",
    "bin_false_dirty_rate": "<= 0.02",
    "face_recall": ">= 0.95",
    "face_precision": ">= 0.80",
    "uncertain_per_clean_cycle_median": "<= 1",
}


def _report(slices: list[dict[str, Any]]) -> dict[str, Any]:
    arms = {
        a: summarise([b for s in slices for b in s["bins"][a]], [x for s in slices for x in s["latency_ms"][a]])
        for a in ARMS
    }
    return {
        "cycles": sum(len(s["bins"]["references"]) for s in slices),
        "slices": [{k: s["setup"][k] for k in ("seed", "first", "cycles", "seconds", "loadavg_1m")} for s in slices],
        "arms": arms,
        "targets": TARGETS,
        "setup": {k: v for k, v in slices[0]["setup"].items() if k not in ("first", "cycles", "seconds", "loadavg_1m")},
    }


def bench_commissioned(opts: BenchOptions, first: int = 0) -> dict[str, Any]:
    """Cycles ``first .. first + n - 1`` (default n 50); returns the slice: the report and every bin's record."""
    import torch

    torch.set_num_threads(1)  # 2 shared cores: more threads only contend
    cfg = opts.load_config()
    n = opts.n or 50
    t0 = time.perf_counter()
    sc = _Scene(opts, cfg)
    print("bench inspect --commissioned: commissioning", file=sys.stderr)
    refs = commission(sc, opts.seed)
    lat: dict[str, list[float]] = {a: [] for a in ARMS}
    bins: dict[str, list[dict[str, Any]]] = {a: [] for a in ARMS}
    for i in range(first, first + n):
        rec = _cycle(sc, refs, opts, i, lat)
        for a in ARMS:
            bins[a].append({"cycle": i, **rec[a]})
        if (i - first + 1) % 5 == 0:
            print(
                f"bench inspect --commissioned: {i - first + 1}/{n}, {time.perf_counter() - t0:.0f} s", file=sys.stderr
            )
    one = {
        "bins": bins,
        "latency_ms": {a: [round(x, 3) for x in v] for a, v in lat.items()},
        "setup": {
            "seed": opts.seed,
            "first": first,
            "cycles": n,
            "bin": BENCH_BIN,
            "render_px": [sc.intr.width, sc.intr.height],
            "parking_error_mm_deg": list(PARKING_ERROR),
            "bin_pose_error_max_mm_deg": list(BIN_POSE_ERROR),
            "kinds": list(KINDS),
            "light_offset_m": list(CELL_LIGHTS),
            "decal_families": list(DECAL_FAMILIES),
            "plans": {s: len(p.viewpoints) for s, p in sc.plans.items()},
            "models": {s: d.model_id for s, d in sc.dets.items()},
            "fusions": {s: f.card.get("model_id") for s, f in sc.fusions.items()},
            "verdict_rule": cfg.classifier.verdict.model_dump(),
            "relook": cfg.classifier.relook.model_dump(),
            "torch_threads": 1,
            "seconds": round(time.perf_counter() - t0, 1),
            "loadavg_1m": round(os.getloadavg()[0], 2),
            "command": f"cellctl bench inspect --commissioned --seed {opts.seed} --seed-offset {first} --cycles {n}",
        },
    }
    return {**_report([one]), "slice": one}


def bench_inspect_commissioned(opts: BenchOptions) -> dict[str, Any]:
    """``cellctl bench inspect --commissioned``: the slice from ``opts.first``, or the merge of ``opts.merge``."""
    return merge(list(opts.merge)) if opts.merge else bench_commissioned(opts, opts.first)


def merge(paths: list[Path | str]) -> dict[str, Any]:
    """The report of slices written by :func:`bench_commissioned` (their ``slice`` records), in cycle order.

    Raises:
        ConfigError: a file is no slice, slices of different seeds or setups, or overlapping cycles.
    """
    from cellctl.errors import ConfigError

    slices = []
    for p in paths:
        try:
            blob = json.loads(Path(p).read_text())
            slices.append(blob["slice"])
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise ConfigError(f"{str(p)!r} is not a bench inspect --commissioned slice: {err}") from err
    seeds = {s["setup"]["seed"] for s in slices}
    if len(seeds) != 1:
        raise ConfigError(f"slices of different seeds {sorted(seeds)} do not make one run")
    slices.sort(key=lambda s: s["setup"]["first"])
    seen: set[int] = set()
    for s in slices:
        cyc = {b["cycle"] for b in s["bins"]["references"]}
        if cyc & seen:
            raise ConfigError(
                f"slice from cycle {s['setup']['first']} overlaps another: cycles {sorted(cyc & seen)[:5]}"
            )
        seen |= cyc
    return {**_report(slices), "merged": [str(p) for p in paths]}
