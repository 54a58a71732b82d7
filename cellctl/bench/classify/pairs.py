"""Generated (reference, new view) pairs of the same planned viewpoint, for the reference decision.

A pair is two twin renders (:class:`cellctl.sim.render.SimRenderer`) of one viewpoint: the
*reference* (clean bin) and the *new view* from a perturbed camera pose (the demo's parking
error: translation and rotation of given size about a random axis), with its own exposure,
light level, sensor noise, white balance and JPEG. A dirty new view carries either a
contamination layer (:mod:`cellctl.classify.contamination`; the training families for fitting,
the held-out ones of :mod:`cellctl.classify.shifted` for measuring) on the inspected surface's
pixels, labelled by the one visibility rule (:func:`~cellctl.classify.contamination.visible_mask`
at the detector's input), or the twin's own powder (labelled by its visible-powder rule).

**Mirrors.** The twin's polished steel reflects a cabin environment at infinity, not the arm
and camera in front of it. Internal views therefore get a one-bounce overlay
(:func:`mirror_overlay`): each internal pixel's reflected ray is tested against the camera body
(a sphere at the camera) and the arm's last links (a capsule from the camera up out of the bin);
a hit shows their colour at the mirror's reflectance. The overlay moves with the camera, so a
pose delta moves it against the steel by about ``f·t/d`` pixels: what the alignment cannot
absorb and the comparison must tolerate.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.classify.contamination import (
    CLUTTER_K,
    FAMILIES,
    MODEL_INPUT_PX,
    VISIBLE_ALPHA,
    Optics,
    composite,
    draw_family,
    optics,
    visible_mask,
)
from cellctl.classify.reference import Plane, plane_from_depth
from cellctl.classify.sample import MIN_CONTRAST, label_from_mask
from cellctl.classify.shifted import HELD_OUT_FAMILIES
from cellctl.errors import ClassifierError

__all__ = [
    "BIN_POSE_ERROR",
    "DEMO_PARKING_ERROR",
    "Pair",
    "make_pair_source",
    "mirror_overlay",
    "perturb",
    "rigid_error",
]

DEMO_PARKING_ERROR = (10.0, 0.5)
"""Translation (mm) and rotation (degrees) of the new view's camera against the reference's: the
demo's parking error left after the plan is adjusted to the measured bin pose."""
RENDER_WIDTH = 256
"""Render width (px, 16:9): the detector's training renders' size."""
MIRROR_REFLECTANCE = 0.6
"""Share of a polished pixel's colour a mirrored object replaces (the twin's cabin term is 0.75)."""
CAMERA_RADIUS_M = 0.05
ARM_RADIUS_M = 0.045
ARM_LENGTH_M = 0.6
ARM_RGB = (175.0, 180.0, 188.0)
CAMERA_RGB = (30.0, 30.0, 34.0)
TWIN_POWDER_SHARE = 0.25
"""Share of dirty pairs that keep the twin's own powder render (the others get a family layer)."""


@dataclass(frozen=True)
class Pair:
    """One generated pair. Images are RGB uint8 at the render size (16:9).

    Attributes:
        ref, new: reference and new view.
        mask: (H, W) visible contamination of the new view (the detector's patch labels).
        label: 1 dirty, 0 clean.
        T_ref, T_new: (4, 4) camera poses in the bin frame.
        K: (3, 3) intrinsics of both images.
        plane: the viewed plane in the reference camera's frame (from the reference depth).
        info: family, bin, surface, delta (mm, deg), render parameters.
    """

    ref: NDArray[np.uint8] = field(repr=False)
    new: NDArray[np.uint8] = field(repr=False)
    mask: NDArray[np.float32] = field(repr=False)
    label: int
    T_ref: NDArray[np.float64] = field(repr=False)
    T_new: NDArray[np.float64] = field(repr=False)
    K: NDArray[np.float64] = field(repr=False)
    plane: Plane
    info: dict[str, Any]


def perturb(T: NDArray[np.float64], mm: float, deg: float, rng: np.random.Generator) -> NDArray[np.float64]:
    """``T`` moved by ``mm`` along and turned by ``deg`` about random axes (camera frame)."""
    from cellctl.geometry.transforms import rotation_about, transform_from

    u = rng.normal(size=3)
    ax = rng.normal(size=3)
    D = transform_from(rotation_about(ax / np.linalg.norm(ax), np.radians(deg)), u / np.linalg.norm(u) * mm / 1000.0)
    return np.asarray(T, np.float64) @ D


BIN_POSE_ERROR = (2.5, 0.3)
"""Largest error (mm, degrees) of the measured bin pose a cycle's plan is adjusted to (uniform magnitude)."""
CYCLE_LIGHT_SCALE = (0.8, 1.2)
"""Light level of a cycle (and of the commissioning one), drawn independently: the cabin's lamps age and
the hall's daylight changes; the lamps do not move (the cell's fixed lights)."""
CYCLE_EXPOSURE = (0.8, 1.2)


def rigid_error(rng: np.random.Generator, mm: float, deg: float, uniform: bool) -> NDArray[np.float64]:
    """``uniform``: magnitudes U(0, mm), U(0, deg) along/about random axes (a pose measurement's error);
    else a parking error: ``mm`` along a random horizontal direction and ``±deg`` of yaw (bin frame)."""
    from cellctl.geometry.transforms import rotation_about, transform_from

    if uniform:
        t, ax = rng.normal(size=3), rng.normal(size=3)
        t = t / np.linalg.norm(t) * rng.uniform(0, mm) / 1000.0
        return transform_from(rotation_about(ax / np.linalg.norm(ax), np.radians(rng.uniform(0, deg))), t)
    a = rng.uniform(0, 2 * np.pi)
    t = np.array([np.cos(a), np.sin(a), 0.0]) * mm / 1000.0
    return transform_from(rotation_about((0, 0, 1), np.radians(deg * rng.choice([-1.0, 1.0]))), t)


def _cycle_poses(T_plan: NDArray[np.float64], park: tuple[float, float], rng: np.random.Generator) -> tuple:
    """Reference and new view of one planned viewpoint as a commissioned cycle takes them.

    Each is taken with the bin parked off by ``park`` in the cabin and the camera at the plan in the
    *measured* bin frame, which is off by up to :data:`BIN_POSE_ERROR`: the camera truly stands at
    ``E @ T_plan`` in the bin frame. Returns ``(T_ref, T_new, T_wb_ref, T_wb_new, T_ref_true,
    T_new_true)``: the poses the comparison is told (both the plan — the cycle knows only measured
    poses), the bin's two cabin poses and the cameras' true poses in the bin frame.
    """
    out = []
    for _ in range(2):
        P = rigid_error(rng, park[0], park[1], uniform=False)
        E = rigid_error(rng, *BIN_POSE_ERROR, uniform=True)
        out.append((P, E @ T_plan))
    (P_r, T_r), (P_n, T_n) = out
    return T_plan, T_plan, P_r, P_n, T_r, T_n


def _cycle_params(rng: np.random.Generator) -> Any:
    """One view's appearance in a cycle: exposure, light level, sensor noise; lights fixed in the cabin."""
    from cellctl.sim.render import RenderParams

    return RenderParams(
        exposure=float(rng.uniform(*CYCLE_EXPOSURE)),
        light_scale=float(rng.uniform(*CYCLE_LIGHT_SCALE)),
        light_offset=(0.0, 0.0, 0.0),
        noise_sigma=float(rng.uniform(1.0, 3.0)),
    )


def _ray_segment_distance(
    p: NDArray[np.float64], r: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Closest distance between rays ``p + s r`` (s ≥ 0, unit r; (M, 3)) and the segment ``a``–``b``."""
    u = b - a
    w0 = p - a
    uu = float(u @ u)
    ru = r @ u
    rw = np.einsum("ij,ij->i", r, w0)
    uw = w0 @ u
    den = np.maximum(uu - ru * ru, 1e-12)
    s = np.clip((ru * uw - uu * rw) / den, 0.0, None)
    t = np.clip((uw + s * ru) / uu, 0.0, 1.0)
    s = np.clip(np.einsum("ij,ij->i", r, a + t[:, None] * u - p), 0.0, None)
    d = p + s[:, None] * r - (a + t[:, None] * u)
    return np.linalg.norm(d, axis=1)


def mirror_overlay(
    rgb: NDArray[np.uint8],
    depth: NDArray[np.float32],
    polished: NDArray[np.bool_],
    T_bin_cam: NDArray[np.float64],
    K: NDArray[np.float64],
    caster: Any,
    face_normals: NDArray[np.float64],
) -> NDArray[np.uint8]:
    """The view with the camera body and arm mirrored in its polished pixels (one bounce).

    Args:
        rgb: (H, W, 3) render; depth: (H, W) optical-axis depth (m); polished: internal pixels.
        T_bin_cam: camera pose in the bin frame; K: intrinsics.
        caster: :class:`cellctl.classify.heatmap.MeshCaster` of the bin mesh (face of each pixel).
        face_normals: (F, 3) the mesh's face normals (bin frame).
    """
    ys, xs = np.nonzero(polished & np.isfinite(depth))
    if len(ys) == 0:
        return rgb
    Kinv = np.linalg.inv(K)
    d_cam = np.c_[xs, ys, np.ones(len(xs))] @ Kinv.T
    R, eye = T_bin_cam[:3, :3], T_bin_cam[:3, 3]
    p = eye + (d_cam * depth[ys, xs, None]) @ R.T
    d = d_cam @ R.T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    face, _ = caster.cast(np.broadcast_to(eye, d.shape).copy(), d)
    hit = face >= 0
    n = np.zeros_like(d)
    n[hit] = face_normals[face[hit]]
    n *= np.where(np.einsum("ij,ij->i", n, d) > 0, -1.0, 1.0)[:, None]
    r = d - 2 * np.einsum("ij,ij->i", d, n)[:, None] * n
    po = p + 1e-3 * n
    # the camera body: a sphere about its optical centre; the arm: a capsule from just behind
    # the camera up out of the bin (the flange and forearm that hold an eye-in-hand camera)
    cam = _ray_segment_distance(po, r, eye, eye + 1e-6) < CAMERA_RADIUS_M
    base = eye - 0.05 * R[:, 2]
    arm = _ray_segment_distance(po, r, base, base + np.array([0.0, 0.0, ARM_LENGTH_M])) < ARM_RADIUS_M
    m = np.zeros(rgb.shape[:2], np.float32)
    col = np.zeros((*rgb.shape[:2], 3), np.float32)
    sel = hit & (cam | arm)
    m[ys[sel], xs[sel]] = MIRROR_REFLECTANCE
    col[ys[sel & arm], xs[sel & arm]] = ARM_RGB
    col[ys[sel & cam], xs[sel & cam]] = CAMERA_RGB
    # anti-aliasing of the hard ray-test edge (a one-sample-per-pixel render)
    m = cv2.GaussianBlur(m, (0, 0), 0.7)
    col = (
        cv2.GaussianBlur(col, (0, 0), 0.7)
        / np.maximum(cv2.GaussianBlur((col.sum(2) > 0).astype(np.float32), (0, 0), 0.7), 1e-3)[..., None]
    )
    out = rgb.astype(np.float32) * (1 - m[..., None]) + col * m[..., None]
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def _view(
    surface: str,
    mesh: Any,
    faces: NDArray,
    w: NDArray,
    hole_r: float,
    rng: np.random.Generator,
    target: NDArray | None = None,
    normal: NDArray | None = None,
) -> NDArray[np.float64]:
    """A camera pose facing the surface: external on the face normal at 0.3–0.6 m, internal from
    the top opening (as the twin source's sampled views)."""
    from cellctl.geometry.transforms import look_at

    if target is None:
        f = int(rng.choice(faces, p=w))
        tri = mesh.vertices[mesh.faces[f]]
        a, b = rng.uniform(size=2)
        if a + b > 1:
            a, b = 1 - a, 1 - b
        target = tri[0] + a * (tri[1] - tri[0]) + b * (tri[2] - tri[0])
        normal = mesh.normals[f]
    if surface == "external":
        n = normal / np.linalg.norm(normal)
        tilt = rng.normal(0, 0.15, 3)
        dvec = n + tilt - (tilt @ n) * n
        eye = target + rng.uniform(0.3, 0.6) * dvec / np.linalg.norm(dvec)
    else:
        rr = hole_r * 0.6 * np.sqrt(rng.uniform())
        ang = rng.uniform(0, 2 * np.pi)
        eye = np.array([rr * np.cos(ang), rr * np.sin(ang), rng.uniform(0.0, 0.15)])
    up = (0.0, 0.0, 1.0) if abs((target - eye)[2]) < 0.95 * np.linalg.norm(target - eye) else (1.0, 0.0, 0.0)
    return look_at(eye, target, up, roll_rad=float(rng.uniform(-np.pi, np.pi)))


def _new_optics(rng: np.random.Generator) -> Optics:
    """The new view's camera effects against the reference's: white balance, noise, JPEG."""
    return Optics(
        white_balance=tuple(float(v) for v in rng.uniform(0.92, 1.08, 3)),
        noise_sigma=float(rng.uniform(0.0, 3.0)),
        jpeg_quality=int(rng.integers(70, 96)) if rng.random() < 0.5 else None,
        noise_seed=int(rng.integers(2**31)),
    )


def make_pair_source(
    surface: str, config: Any = None, mirror: bool = True, cycle: bool = True
) -> Callable[..., Pair | None]:
    """A ``draw(rng, dirty, held_out=False, delta=DEMO_PARKING_ERROR) -> Pair | None`` of twin pairs.

    ``cycle`` (default) draws a pair the way a commissioned cycle sees it (:func:`_cycle_poses`,
    :func:`_cycle_params`): ``delta`` is the bin's parking error; else (the first fit, kept for
    the mirror sweep) the camera moves by ``delta`` against a bin that stays put under the lights.

    ``None`` = an ambiguous dirty draw or a view that shows too little of the surface (draw again).
    ``held_out`` picks the shifted generator's families (measurement only).
    """
    from cellctl.classify.heatmap import MeshCaster
    from cellctl.config import load_config
    from cellctl.geometry.camera import D435_COLOR
    from cellctl.geometry.catalog import load_catalog
    from cellctl.sim.render import RenderParams, SimRenderer
    from cellctl.sim.scene import Scenario
    from cellctl.surface import FACE_TAG, check_surface

    cfg = config if config is not None else load_config()
    catalog = load_catalog(cfg.path(cfg.catalog), cfg.root)
    renderer = SimRenderer(catalog)
    intr = D435_COLOR.scaled(RENDER_WIDTH / D435_COLOR.width)
    K = intr.K()
    tag = FACE_TAG[check_surface(surface, ClassifierError)]
    bins: dict[str, tuple] = {}
    for name in catalog.names:
        mesh = catalog.load_mesh(name)
        faces = np.flatnonzero(mesh.surface == tag)
        if len(faces):
            areas = mesh.areas[faces]
            bins[name] = (mesh, faces, areas / areas.sum(), MeshCaster(mesh), catalog.get(name).top_hole_radius_m)
    if not bins:
        raise ClassifierError(f"no bin type in the catalog has {surface} faces")
    names = sorted(bins)
    nominal = {n: Scenario(bin_type=n).T_world_bin(catalog.get(n)) for n in names}

    def render(
        name: str, T: NDArray, P: Any, dirty: bool, amount: float, seed: int, over: bool, T_wb: NDArray | None = None
    ) -> Any:
        if T_wb is None:
            out = renderer.render_bin_view(name, T, intr, dirty=dirty, powder_amount=amount, seed=seed, params=P)
        else:
            # the bin parked at T_wb in the cabin (render_bin_view stands it at the nominal pose)
            field_ = renderer.powder(name, dirty, amount, seed)
            out = renderer._render(name, T_wb, None, None, T_wb @ T, intr, P, seed, field_, True)
        rgb = out.rgb
        if over and mirror and surface == "internal":
            mesh, _, _, caster, _ = bins[name]
            rgb = mirror_overlay(rgb, out.depth, out.surface == tag, T, K, caster, mesh.normals)
        return out, rgb

    def draw(
        rng: np.random.Generator, dirty: bool, held_out: bool = False, delta: tuple[float, float] = DEMO_PARKING_ERROR
    ) -> Pair | None:
        name = names[int(rng.integers(len(names)))]
        mesh, faces, w, _, hole_r = bins[name]
        twin_powder = dirty and rng.random() < TWIN_POWDER_SHARE
        pseed = int(rng.integers(2**31))
        amount = float(rng.uniform(0.3, 1.0))
        target = normal = None
        if twin_powder:
            field_ = renderer.powder(name, True, amount, pseed)
            mine = np.flatnonzero(field_.surface == tag)
            if len(mine) == 0:
                return None
            k = int(rng.choice(mine))
            target, normal = field_.centres[k], field_.normals[k]
        T_plan = _view(surface, mesh, faces, w, hole_r, rng, target, normal)
        if cycle:
            # both the commissioning and the cycle park the bin off (under the cell's fixed lights, so
            # highlights slide over the steel) and reach the plan in the *measured* bin frame
            poses = _cycle_poses(T_plan, delta, rng)
            T_ref, T_new, park_ref, park_new, T_ref_true, T_new_true = poses
            T_wb_ref, T_wb_new = nominal[name] @ park_ref, nominal[name] @ park_new
            P_ref, P_new = _cycle_params(rng), _cycle_params(rng)
        else:
            T_ref, T_new = T_plan, perturb(T_plan, delta[0], delta[1], rng)
            T_wb_ref = T_wb_new = None
            T_ref_true, T_new_true = T_ref, T_new
            light = tuple(float(v) for v in rng.uniform([-0.3, -0.3, -0.2], [0.3, 0.3, 0.2]))
            e, ls = float(rng.uniform(0.8, 1.2)), float(rng.uniform(0.85, 1.15))
            P_ref = RenderParams(
                exposure=e, light_scale=ls, light_offset=light, noise_sigma=float(rng.uniform(0.5, 2.5))
            )
            P_new = RenderParams(
                exposure=e * float(rng.uniform(0.8, 1.25)),
                light_scale=ls * float(rng.uniform(0.95, 1.05)),
                light_offset=light,
                noise_sigma=float(rng.uniform(0.5, 2.5)),
            )
        ref_out, ref = render(name, T_ref_true, P_ref, False, 0.0, int(rng.integers(2**31)), True, T_wb_ref)
        if float((ref_out.surface == tag).mean()) < 0.5:
            return None
        try:
            plane = plane_from_depth(ref_out.depth, K)
        except ClassifierError:
            return None
        nseed = int(rng.integers(2**31))
        new_out, new_clean = render(name, T_new_true, P_new, False, 0.0, nseed, True, T_wb_new)
        opt = _new_optics(rng)
        on_surface = new_out.surface == tag
        info: dict[str, Any] = {
            "bin": name,
            "surface": surface,
            "delta_mm": delta[0],
            "delta_deg": delta[1],
            "cycle": cycle,
        }
        if not dirty:
            new = optics(new_clean.astype(np.float32) / 255.0, opt)
            return Pair(
                ref, new, np.zeros(new.shape[:2], np.float32), 0, T_ref, T_new, K, plane, {**info, "family": "none"}
            )
        if twin_powder:
            pow_out, pow_rgb = render(name, T_new_true, P_new, True, amount, nseed, True, T_wb_new)
            vis = pow_out.powder_mask & (
                np.abs(pow_rgb.astype(np.int16) - new_clean.astype(np.int16)).max(2) >= MIN_CONTRAST
            )
            if label_from_mask(vis.astype(np.float32), present=float(pow_out.powder_mask.mean())) != "dirty":
                return None
            new = optics(pow_rgb.astype(np.float32) / 255.0, opt)
            return Pair(ref, new, vis.astype(np.float32), 1, T_ref, T_new, K, plane, {**info, "family": "twin_powder"})
        table = HELD_OUT_FAMILIES if held_out else FAMILIES
        fams = sorted(table)
        fam = fams[int(rng.integers(len(fams)))]
        base = new_clean.astype(np.float32) / 255.0
        img, alpha = composite(base, draw_family(fam, base.shape[0], base.shape[1], rng, table), on_surface)
        new, clean = optics(img, opt), optics(base, opt)
        seen = visible_mask(new, clean, alpha, at_px=MODEL_INPUT_PX, clutter_k=CLUTTER_K)
        if label_from_mask(seen, present=float((alpha >= VISIBLE_ALPHA).mean())) != "dirty":
            return None
        h, wd = new.shape[:2]
        vis = (cv2.resize(seen, (wd, h), interpolation=cv2.INTER_NEAREST) > 0) & (alpha >= VISIBLE_ALPHA)
        return Pair(ref, new, vis.astype(np.float32), 1, T_ref, T_new, K, plane, {**info, "family": fam})

    return draw
