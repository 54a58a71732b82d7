"""Change detection against a commissioned reference view: align, compare, fuse with the detector.

A planned viewpoint is revisited every cycle from nearly the same pose, so the view taken when the
bin was known clean (its *reference*) shows the same seams, scratches, brushing and mirrored cabin.
What differs after alignment is what is new. The stages, each a function over typed records:

1. **Align** (:func:`align`): the pose delta between the two camera poses (both in the bin frame)
   and the viewed plane give the initial homography ``H = K (R + t nᵀ/d) K⁻¹``
   (:func:`homography_from_poses`, reference pixels → new pixels); ECC with
   ``MOTION_HOMOGRAPHY`` on the grey log image (exposure and white balance are offsets there,
   which ECC's correlation ignores) refines it. The alignment is **rejected**, with a reason, when
   ECC does not converge, its correlation is below :data:`MIN_CORRELATION`, the refined
   homography moves points inside the view by more than :data:`MAX_PRIOR_SHIFT_PX` (RMS) from the
   pose prior, or
   the warped reference covers less than :data:`MIN_OVERLAP` of the view (:class:`Alignment`).
2. **Compare** (:func:`change_features`): in log-RGB, after removing each channel's median offset
   over the overlap (a global exposure and white-balance change is exactly such an offset), per
   detector patch (16×16 at the 128 px input): the mean colour residual, the structure
   energy and the log contrast ratio, inside a ±2 px envelope of the reference. A fitted logistic
   (:class:`ReferenceFusion`) turns them into a **change logit** ``c`` per patch.
3. **Fuse** (:func:`decide`): ``z = w_s·s + w_a·a + w_c·c + g·(w_gs·s + w_ga·a) + b`` per patch
   (detector head logit ``s``, memory-bank distance ``a``, change logit ``c``, ``g = sigmoid(c)``):
   the detector's evidence may weigh more where something changed — the mirrored arm, a seam or a
   reflection is anomalous to the detector on every visit, and the reference already shows it.
   Platt scaling on the image's largest ``z`` and a
   threshold chosen on generated pairs for the false-clean target. Without a reference, or with a
   rejected alignment, the detector decides alone and the result says why
   (:class:`ReferenceDecision`). On polished (internal) steel a pose delta past
   :data:`MIRROR_POSE_TOLERANCE` is rejected before any image work (``out_of_tolerance``): the
   mirrored arm, camera and cabin no longer line up with the reference.

The fused weights live in ``<models_dir>/<surface>.reference.json`` (:data:`FUSION_FORMAT`), fitted
by ``cellctl bench reference`` (:mod:`cellctl.bench.classify.reference`, on generated pairs);
measurements are in ``docs/classifier/reference.md``.

Light: numpy + OpenCV at import; the detector (torch) is passed in.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, get_args

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.classify.contamination import MODEL_INPUT_PX
from cellctl.classify.decision import is_uncertain
from cellctl.errors import ClassifierError
from cellctl.messages.classifier import ReferenceReason

__all__ = [
    "FUSION_FORMAT",
    "MAX_PRIOR_SHIFT_PX",
    "MIN_CORRELATION",
    "MIN_OVERLAP",
    "MIRROR_POSE_TOLERANCE",
    "REJECT_REASONS",
    "Alignment",
    "Plane",
    "PoseTolerance",
    "ReferenceDecision",
    "ReferenceFusion",
    "ReferenceView",
    "align",
    "change_features",
    "decide",
    "fusion_inputs",
    "fusion_path",
    "homography_from_poses",
    "plane_from_depth",
    "plane_from_mesh",
    "pose_delta",
    "reference_view",
    "squash_matrix",
    "to_work",
    "warp_reference",
]

WORK_PX = MODEL_INPUT_PX
"""Side of the square both images are squashed to (the detector's input): alignment, comparison
and the detector share one resize."""
GRID = WORK_PX // 8
"""Patch grid side (16): the detector's."""
MIN_CORRELATION = 0.5
"""Smallest ECC correlation of an accepted alignment. Clean pairs at the demo's parking error
reach 0.8–0.99 (``docs/classifier/reference.md``); a view dominated by something new (a large
film, a hand, a different bin) drops below."""
MAX_PRIOR_SHIFT_PX = 12.0
"""Largest RMS move (work px, 1.5 patches) of a 5×5 grid inside the view between the pose prior and
the refined homography: clean pairs at the demo's parking error move it by 0.5–6 px (a plane fitted
to a view into a corner is only approximate); more means ECC locked onto something else (a mirrored
reflection, a repeating seam)."""
MIN_OVERLAP = 0.6
"""Smallest share of the view the warped reference must cover."""
ECC_ITERATIONS = 40
ECC_EPS = 1e-3
"""ECC stops when the update moves the warp parameters by less than this (a few hundredths of a
pixel at 128 px): tighter only costs iterations (3 ms → 10 ms) for no change in the change map."""
LOG_EPS = 0.02
"""Added before the log (in [0, 1] units): keeps sensor noise in black pixels from dominating."""
TEXTURE_FLOOR = 0.05
"""Patch std (log units) below which a patch counts as flat in the contrast ratio."""
ENVELOPE_PX = 2
"""Half-width (work px) of the reference neighbourhood whose value range a new pixel may take
without counting as changed: 2 px at 128 = 1/4 patch, about the residual of ECC plus a plane
homography across a wall edge at the demo's parking error."""
UNCOVERED_FEATURES = (0.0, 0.0, 0.0)
"""Change features of a patch the warped reference does not cover: no evidence of change."""
FUSION_FORMAT = "cellctl-reference-fusion/2"
"""2: the detector's evidence also enters gated by the change probability (``fuse`` has 6 weights)."""
_NOT_ALIGNMENT = ("aligned", "no_fusion", "unreadable")
"""Reasons the classifier worker gives, not the alignment: judged, no fitted fusion, stored image unreadable."""
REJECT_REASONS: tuple[str, ...] = tuple(r for r in get_args(ReferenceReason) if r not in _NOT_ALIGNMENT)
"""Why the alignment refused a view: the wire's reasons less the worker's own (one list, on the wire)."""


@dataclass(frozen=True)
class PoseTolerance:
    """How far a camera pose may be from its reference pose for the comparison to hold.

    Attributes:
        translation_mm: largest translation of the camera (mm).
        rotation_deg: largest rotation of the camera (degrees).
    """

    translation_mm: float
    rotation_deg: float

    def holds(self, translation_mm: float, rotation_deg: float) -> bool:
        """True when a pose delta lies inside the tolerance."""
        return translation_mm <= self.translation_mm and rotation_deg <= self.rotation_deg


MIRROR_POSE_TOLERANCE = PoseTolerance(translation_mm=7.5, rotation_deg=4.0)
"""Pose delta (camera in the bin frame, reference against now) up to which mirrored content (arm,
camera, cabin in polished internal steel) keeps the clean false-change rate at its zero-delta
level. Measured on twin pairs with the arm and camera mirrored (``docs/classifier/reference.md``,
``docs/classifier/reference.json`` ``mirror``, 20 clean pairs a level): the share of clean pairs
with a changed patch is 25 % from 0 to 5 mm, 40 % at 7.5 mm, 50 % at 10 mm, 65 % at 20 mm; a
rotation about the camera moves mirrored and real content alike (25–30 % up to 4°, the largest
tested). The plan adjusted to the measured bin pose keeps the camera within a few mm of its
reference pose; past this the comparison is skipped (``out_of_tolerance``) and the detector
decides alone. The planner/scan holds it where references are used."""


@dataclass(frozen=True)
class Plane:
    """The viewed planar patch in a camera's optical frame: points ``X`` with ``normal·X = distance``.

    Attributes:
        normal: (3,) unit normal (towards the camera or away: the sign is carried by ``distance``).
        distance: signed distance (m), positive for ``normal`` pointing away from the camera.
    """

    normal: tuple[float, float, float]
    distance: float


@dataclass(frozen=True)
class ReferenceView:
    """One commissioned reference: the clean image, its camera pose and the viewed plane.

    Attributes:
        rgb: (H, W, 3) uint8 image taken when the bin was known clean.
        T_bin_cam: (4, 4) camera optical frame in the bin frame at that moment.
        plane: the viewed plane in that camera's frame (:func:`plane_from_depth` or the mesh).
        K: (3, 3) intrinsics of ``rgb``.
    """

    rgb: NDArray[np.uint8] = field(repr=False)
    T_bin_cam: NDArray[np.float64]
    plane: Plane
    K: NDArray[np.float64]


@dataclass(frozen=True)
class Alignment:
    """Result of :func:`align`. ``H`` maps reference work pixels to new work pixels.

    Attributes:
        ok: the reference may be compared.
        reason: ``"aligned"`` or one of :data:`REJECT_REASONS`.
        H: (3, 3) refined homography (the prior when rejected before refinement).
        H_prior: (3, 3) homography from the pose delta.
        correlation: ECC correlation coefficient (NaN when ECC did not run or failed).
        prior_shift_px: largest corner move from the prior (work px).
        overlap: share of the view the warped reference covers.
    """

    ok: bool
    reason: str
    H: NDArray[np.float64]
    H_prior: NDArray[np.float64]
    correlation: float = math.nan
    prior_shift_px: float = math.nan
    overlap: float = math.nan

    def as_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "reason": self.reason,
            "correlation": _r(self.correlation),
            "prior_shift_px": _r(self.prior_shift_px),
            "overlap": _r(self.overlap),
        }


def _r(v: float) -> float | None:
    return None if not math.isfinite(v) else round(float(v), 4)


# --- geometry ------------------------------------------------------------------------------------


def pose_delta(T_bin_ref: NDArray[np.float64], T_bin_new: NDArray[np.float64]) -> tuple[float, float]:
    """Translation (mm) and rotation (degrees) between two camera poses."""
    D = np.linalg.inv(np.asarray(T_bin_new, np.float64)) @ np.asarray(T_bin_ref, np.float64)
    ang = math.degrees(math.acos(float(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1.0, 1.0))))
    return float(np.linalg.norm(D[:3, 3]) * 1000.0), ang


def homography_from_poses(
    K: NDArray[np.float64], T_bin_ref: NDArray[np.float64], T_bin_new: NDArray[np.float64], plane: Plane
) -> NDArray[np.float64]:
    """The plane-induced homography from reference pixels to new pixels.

    With ``X' = R X + t`` the reference optical frame in the new one and ``n·X = d`` the plane in
    the reference frame, ``X' = (R + t nᵀ/d) X`` for plane points, so ``H = K (R + t nᵀ/d) K⁻¹``.

    Raises:
        ClassifierError: the plane passes through the reference camera (``d`` ≈ 0).
    """
    if abs(plane.distance) < 1e-4:
        raise ClassifierError(f"plane distance {plane.distance!r} m: the plane passes through the camera")
    D = np.linalg.inv(np.asarray(T_bin_new, np.float64)) @ np.asarray(T_bin_ref, np.float64)
    n = np.asarray(plane.normal, np.float64).reshape(3, 1)
    A = D[:3, :3] + D[:3, 3:4] @ n.T / plane.distance
    K = np.asarray(K, np.float64)
    H = K @ A @ np.linalg.inv(K)
    return H / H[2, 2]


def plane_from_depth(
    depth: NDArray[np.floating], K: NDArray[np.float64], min_points: int = 50, inlier_m: float = 0.005
) -> Plane:
    """The dominant plane of a depth image (optical-axis depth, m; non-finite = no return).

    RANSAC (seeded, 64 tries of 3 points) over the back-projected points of the central half of
    the image, inliers within ``inlier_m``, then a least-squares refit on the inliers: a view into
    a corner shows two walls, and one plane through both (a plain least-squares fit) can pass
    near the camera and give a homography that is wrong everywhere.

    Raises:
        ClassifierError: fewer than ``min_points`` valid depths in the centre.
    """
    h, w = depth.shape
    ys, xs = np.mgrid[h // 4 : 3 * h // 4, w // 4 : 3 * w // 4]
    z = np.asarray(depth, np.float64)[ys, xs].ravel()
    ok = np.isfinite(z) & (z > 1e-3)
    if ok.sum() < min_points:
        raise ClassifierError(f"depth image has {int(ok.sum())} valid centre points, expected >= {min_points}")
    Kinv = np.linalg.inv(np.asarray(K, np.float64))
    # OpenCV's convention (the twin's too): integer pixel coordinates are pixel centres
    rays = np.c_[xs.ravel()[ok], ys.ravel()[ok], np.ones(int(ok.sum()))] @ Kinv.T
    P = rays * z[ok, None]
    rng = np.random.default_rng(0)
    best = np.ones(len(P), bool)
    best_n = -1
    for _ in range(64):
        q = P[rng.choice(len(P), 3, replace=False)]
        n = np.cross(q[1] - q[0], q[2] - q[0])
        if np.linalg.norm(n) < 1e-12:
            continue
        n /= np.linalg.norm(n)
        inl = np.abs((P - q[0]) @ n) <= inlier_m
        if inl.sum() > best_n:
            best, best_n = inl, int(inl.sum())
    c = P[best].mean(0)
    _, _, vt = np.linalg.svd(P[best] - c, full_matrices=False)
    n = vt[2]
    d = float(n @ c)
    if d < 0:
        n, d = -n, -d
    return Plane((float(n[0]), float(n[1]), float(n[2])), d)


def plane_from_mesh(
    caster: Any, mesh: Any, T_bin_cam: NDArray[np.float64], K: NDArray[np.float64], width: int, height: int
) -> Plane:
    """The viewed plane from the bin mesh: the face normal most of a 9×9 grid of rays through the
    central half of the image hits, through the mean of those hits, in the camera's optical frame.

    For references stored without depth (the commissioning set keeps image, poses and intrinsics).

    Args:
        caster: :class:`cellctl.classify.heatmap.MeshCaster` of ``mesh`` (bin frame).
        mesh: the bin mesh (``vertices``, ``faces``, ``normals``).
        T_bin_cam: (4, 4) the camera in the bin frame; K: its intrinsics at ``width``×``height``.

    Raises:
        ClassifierError: no ray of the grid hits the bin.
    """
    g = np.linspace(0.25, 0.75, 9)
    xs, ys = np.meshgrid(g * (width - 1), g * (height - 1))
    d_cam = np.c_[xs.ravel(), ys.ravel(), np.ones(xs.size)] @ np.linalg.inv(np.asarray(K, np.float64)).T
    T = np.asarray(T_bin_cam, np.float64)
    d = d_cam @ T[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    face, bary = caster.cast(np.broadcast_to(T[:3, 3], d.shape).copy(), d)
    hit = face >= 0
    if not hit.any():
        raise ClassifierError(
            f"no ray through the centre of the view hits the bin (camera at {T[:3, 3].round(3).tolist()})"
        )
    normals = np.asarray(mesh.normals, np.float64)[face[hit]]
    # one plane: the normal most hits share (faces of one flat wall share it to rounding)
    keys = [tuple(k) for k in np.round(normals, 2)]
    best = max(set(keys), key=keys.count)
    sel = np.array([k == best for k in keys])
    tri = np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.faces)[face[hit][sel]]]
    u, v = bary[hit][sel, 0:1].astype(np.float64), bary[hit][sel, 1:2].astype(np.float64)
    pts = (1 - u - v) * tri[:, 0] + u * tri[:, 1] + v * tri[:, 2]
    n_cam = T[:3, :3].T @ normals[sel][0]
    c_cam = T[:3, :3].T @ (pts.mean(0) - T[:3, 3])
    dist = float(n_cam @ c_cam)
    if dist < 0:
        n_cam, dist = -n_cam, -dist
    return Plane((float(n_cam[0]), float(n_cam[1]), float(n_cam[2])), dist)


def reference_view(
    rgb: NDArray[np.uint8],
    T_base_cam: NDArray[np.float64],
    T_base_bin: NDArray[np.float64],
    K: NDArray[np.float64],
    caster: Any,
    mesh: Any,
) -> ReferenceView:
    """A stored reference (image, camera and bin pose in the robot base frame, intrinsics at the
    image's size) as a :class:`ReferenceView`: the camera in the bin frame and the viewed plane
    from the mesh. The new view's pose must be taken in the bin frame the same way (its own
    measured bin pose): a bin parked elsewhere moves both camera poses, not their delta."""
    T_bin_cam = np.linalg.inv(np.asarray(T_base_bin, np.float64)) @ np.asarray(T_base_cam, np.float64)
    h, w = rgb.shape[:2]
    return ReferenceView(rgb, T_bin_cam, plane_from_mesh(caster, mesh, T_bin_cam, K, w, h), np.asarray(K, np.float64))


def squash_matrix(width: int, height: int, size: int = WORK_PX) -> NDArray[np.float64]:
    """Pixel map of the squash to ``size``×``size`` (the detector's resize of a whole frame):
    ``cv2.resize`` maps pixel centres by ``x' = s (x + ½) − ½``."""
    sx, sy = size / width, size / height
    return np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])


def to_work(rgb: NDArray[np.uint8], size: int = WORK_PX) -> NDArray[np.uint8]:
    """The image squashed to the work size exactly as the detector's ``prepare`` does."""
    if rgb.shape[0] == size and rgb.shape[1] == size:
        return rgb
    shrink = rgb.shape[0] > size and rgb.shape[1] > size
    return cv2.resize(rgb, (size, size), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


# --- align ---------------------------------------------------------------------------------------


def _log_rgb(rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
    return np.log(rgb.astype(np.float32) * np.float32(1 / 255.0) + np.float32(LOG_EPS))


def _registration_image(rgb: NDArray[np.uint8]) -> NDArray[np.float32]:
    # grey of log-RGB: a gain per channel (exposure, white balance) becomes an offset, which
    # ECC's zero-mean normalised correlation ignores
    return np.ascontiguousarray(_log_rgb(rgb).mean(axis=2))


def _prior_shift(H: NDArray[np.float64], H0: NDArray[np.float64], size: int) -> float:
    """RMS move (work px) between two homographies over a 5×5 grid inside the view: image corners
    extrapolate the perspective terms, which a view of mostly one flat wall leaves loose."""
    g = (np.arange(5) + 0.5) * size / 5
    xs, ys = np.meshgrid(g, g)
    c = np.stack([xs.ravel(), ys.ravel(), np.ones(25)])
    a, b = H @ c, H0 @ c
    return float(np.sqrt((np.linalg.norm(a[:2] / a[2] - b[:2] / b[2], axis=0) ** 2).mean()))


def _overlap(H: NDArray[np.float64], size: int) -> tuple[NDArray[np.bool_], float]:
    ones = np.full((size, size), 255, np.uint8)
    cover = cv2.warpPerspective(ones, H, (size, size), flags=cv2.INTER_NEAREST, borderValue=0) > 0
    return cover, float(cover.mean())


def align(ref_work: NDArray[np.uint8], new_work: NDArray[np.uint8], H_prior: NDArray[np.float64]) -> Alignment:
    """Refine the pose prior ``H_prior`` (reference work px → new work px) by ECC.

    Both images are ``WORK_PX`` squares (:func:`to_work`). Never raises on a bad pair: a failure
    is an :class:`Alignment` with ``ok=False`` and its reason.
    """
    size = new_work.shape[0]
    H0 = np.asarray(H_prior, np.float64)
    if not np.isfinite(H0).all() or abs(np.linalg.det(H0)) < 1e-6:
        return Alignment(False, "degenerate_prior", H0, H0)
    H0 = H0 / H0[2, 2]
    _, ov0 = _overlap(H0, size)
    if ov0 < MIN_OVERLAP:
        return Alignment(False, "small_overlap", H0, H0, overlap=ov0)
    # ECC finds W with input(W x) ≈ template(x): template = new view, input = reference,
    # so W maps new pixels to reference pixels (the inverse of H)
    W = np.linalg.inv(H0).astype(np.float32)
    W /= W[2, 2]
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, ECC_ITERATIONS, ECC_EPS)
    try:
        rho, W = cv2.findTransformECC(
            _registration_image(new_work), _registration_image(ref_work), W, cv2.MOTION_HOMOGRAPHY, crit, None, 5
        )
    except cv2.error:
        # OpenCV raises when the correlation collapses (NaN) or the update diverges
        return Alignment(False, "ecc_not_converged", H0, H0)
    if not np.isfinite(W).all() or abs(np.linalg.det(W)) < 1e-6:
        return Alignment(False, "ecc_not_converged", H0, H0)
    H = np.linalg.inv(W.astype(np.float64))
    H /= H[2, 2]
    shift = _prior_shift(H, H0, size)
    _, ov = _overlap(H, size)
    if rho < MIN_CORRELATION:
        return Alignment(False, "low_correlation", H, H0, float(rho), shift, ov)
    if shift > MAX_PRIOR_SHIFT_PX:
        return Alignment(False, "far_from_prior", H, H0, float(rho), shift, ov)
    if ov < MIN_OVERLAP:
        return Alignment(False, "small_overlap", H, H0, float(rho), shift, ov)
    return Alignment(True, "aligned", H, H0, float(rho), shift, ov)


def warp_reference(ref_work: NDArray[np.uint8], H: NDArray[np.float64]) -> tuple[NDArray[np.uint8], NDArray[np.bool_]]:
    """The reference in the new view's pixels and where it is defined (2 px inside its border)."""
    size = ref_work.shape[0]
    warped = cv2.warpPerspective(ref_work, H, (size, size), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    cover, _ = _overlap(H, size)
    valid = cv2.erode(cover.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    return warped, valid


# --- compare -------------------------------------------------------------------------------------


def _patch_mean(x: NDArray[np.float32], w: NDArray[np.float32], grid: int) -> NDArray[np.float32]:
    num = cv2.resize(x * w, (grid, grid), interpolation=cv2.INTER_AREA)
    den = cv2.resize(w, (grid, grid), interpolation=cv2.INTER_AREA)
    return num / np.maximum(den, 1e-6)


def change_features(
    warped_ref: NDArray[np.uint8], new_work: NDArray[np.uint8], valid: NDArray[np.bool_], grid: int = GRID
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Per-patch change features ``(3, grid, grid)`` and patch coverage ``(grid, grid)``.

    In log-RGB, both images blurred σ 1 px, each channel's median offset over the overlap added to
    the reference (a global exposure and white-balance change is exactly that offset). A pixel's
    **envelope residual** is how far the new value lies outside the range of the reference's
    values within ±:data:`ENVELOPE_PX` px (the golden-template tolerance band of print
    inspection): a residual misregistration, a seam or a wall edge the plane homography does not
    fit exactly, and the grain of brushed steel all stay inside it; new matter does not.

    0. colour: norm over channels of the patch-mean envelope residual (powder, stains, soot,
       tarnish: a consistent shift of colour or brightness);
    1. structure: RMS over the patch of the grey envelope residual (new lines and specks: fibres,
       streaks, droplets, flakes, whichever sign);
    2. contrast: ``|½ log((v_n + τ²) / (v_r + τ²))|`` of the grey patch variances (a film that
       veils the texture stays inside the envelope but lowers the contrast).

    Patches covered less than half get :data:`UNCOVERED_FEATURES`.
    """
    ln = cv2.GaussianBlur(_log_rgb(new_work), (0, 0), 1.0)
    lr = cv2.GaussianBlur(_log_rgb(warped_ref), (0, 0), 1.0)
    w = valid.astype(np.float32)
    if w.sum() < 16:
        cover = np.zeros((grid, grid), np.float32)
        return np.zeros((3, grid, grid), np.float32) + np.asarray(UNCOVERED_FEATURES, np.float32)[:, None, None], cover
    lr = lr + np.median((ln - lr)[valid], axis=0)
    kernel = np.ones((2 * ENVELOPE_PX + 1, 2 * ENVELOPE_PX + 1), np.uint8)

    def envelope(n: NDArray[np.float32], r: NDArray[np.float32]) -> NDArray[np.float32]:
        return np.maximum(n - cv2.dilate(r, kernel), 0.0) - np.maximum(cv2.erode(r, kernel) - n, 0.0)

    res = envelope(ln, lr)
    colour = np.sqrt(sum(_patch_mean(np.ascontiguousarray(res[..., c]), w, grid) ** 2 for c in range(3)))
    gn = np.ascontiguousarray(ln.mean(axis=2))
    gr = np.ascontiguousarray(lr.mean(axis=2))
    structure = np.sqrt(_patch_mean(envelope(gn, gr) ** 2, w, grid))
    mn, mr = _patch_mean(gn, w, grid), _patch_mean(gr, w, grid)
    vn = np.maximum(_patch_mean(gn * gn, w, grid) - mn * mn, 0.0)
    vr = np.maximum(_patch_mean(gr * gr, w, grid) - mr * mr, 0.0)
    tau2 = TEXTURE_FLOOR**2
    contrast = np.abs(0.5 * np.log((vn + tau2) / (vr + tau2)))
    cover = cv2.resize(w, (grid, grid), interpolation=cv2.INTER_AREA)
    feats = np.stack([colour, structure, contrast]).astype(np.float32)
    feats[:, cover < 0.5] = np.asarray(UNCOVERED_FEATURES, np.float32)[:, None]
    return feats, cover


# --- fuse ----------------------------------------------------------------------------------------


def fusion_path(models_dir: Path | str, surface: str) -> Path:
    """``<models_dir>/<surface>.reference.json``."""
    return Path(models_dir) / f"{surface}.reference.json"


def _sig(x: NDArray[np.float64] | float) -> NDArray[np.float64]:
    return 1.0 / (1.0 + np.exp(-np.asarray(x, np.float64)))


def fusion_inputs(s: NDArray[np.floating], a: NDArray[np.floating], c: NDArray[np.floating]) -> NDArray[np.float64]:
    """The fused logistic's inputs per patch ``(5, ...)``: ``s, a, c, g·s, g·a`` with ``g = sigmoid(c)``."""
    s64, a64, c64 = (np.asarray(v, np.float64) for v in (s, a, c))
    g = _sig(c64)
    return np.stack([s64, a64, c64, g * s64, g * a64])


@dataclass(frozen=True)
class ReferenceFusion:
    """The fitted weights of the reference decision for one surface.

    Attributes:
        surface: ``external`` or ``internal``.
        change: ``(w_colour, w_structure, w_contrast, b)``: change logit of a patch's features.
        fuse: ``(w_s, w_a, w_c, w_gs, w_ga, b)``: patch logit from head logit, bank distance,
            change logit and the two detector terms gated by the change probability.
        platt: ``(α, β)`` of the image's largest patch logit.
        threshold: dirty at ``p_dirty >= threshold`` (false-clean target on the fit pairs).
        band: uncertain band (logits), the detector's.
        card: provenance (command, seeds, counts, detector model id).
    """

    surface: str
    change: tuple[float, float, float, float]
    fuse: tuple[float, float, float, float, float, float]
    platt: tuple[float, float]
    threshold: float
    band: float
    card: dict[str, Any] = field(default_factory=dict, repr=False)

    def change_logit(self, feats: NDArray[np.float32]) -> NDArray[np.float64]:
        """``(grid, grid)`` change logit of :func:`change_features`' output."""
        w = np.asarray(self.change[:3], np.float64)
        return np.tensordot(w, feats.astype(np.float64), axes=1) + self.change[3]

    def patch_logit(
        self, s: NDArray[np.floating], a: NDArray[np.floating], c: NDArray[np.floating]
    ) -> NDArray[np.float64]:
        return np.tensordot(np.asarray(self.fuse[:5]), fusion_inputs(s, a, c), axes=1) + self.fuse[5]

    def p_image(self, z: NDArray[np.float64]) -> float:
        al, be = self.platt
        return float(_sig(al * float(np.max(z)) + be))

    def save(self, path: Path | str) -> None:
        blob = {
            "format": FUSION_FORMAT,
            "surface": self.surface,
            "change": list(self.change),
            "fuse": list(self.fuse),
            "platt": list(self.platt),
            "threshold": self.threshold,
            "band": self.band,
            "card": self.card,
        }
        Path(path).write_text(json.dumps(blob, indent=1) + "\n")

    @staticmethod
    def load(path: Path | str, surface: str | None = None) -> ReferenceFusion:
        """Read a fusion file.

        Raises:
            ClassifierError: missing, foreign or malformed file, or another surface's.
        """
        p = Path(path)
        try:
            blob = json.loads(p.read_text())
        except (OSError, ValueError) as err:
            raise ClassifierError(f"reference fusion {str(p)!r} cannot be read: {err}") from err
        if not isinstance(blob, dict) or blob.get("format") != FUSION_FORMAT:
            raise ClassifierError(f"{str(p)!r} is not a reference fusion file (expected format {FUSION_FORMAT!r})")
        if surface is not None and blob.get("surface") != surface:
            raise ClassifierError(f"{str(p)!r} is for surface {blob.get('surface')!r}, expected {surface!r}")
        try:
            vals = [float(v) for v in (*blob["change"], *blob["fuse"], *blob["platt"], blob["threshold"], blob["band"])]
            if len(blob["change"]) != 4 or len(blob["fuse"]) != 6 or len(blob["platt"]) != 2:
                raise ValueError("change needs 4 values, fuse 6, platt 2")
        except (KeyError, TypeError, ValueError) as err:
            raise ClassifierError(f"{str(p)!r} is malformed: {err}") from err
        if not all(math.isfinite(v) for v in vals) or not 0 < blob["threshold"] < 1:
            raise ClassifierError(f"{str(p)!r}: non-finite weight or threshold {blob['threshold']!r} outside (0, 1)")
        return ReferenceFusion(
            str(blob["surface"]),
            tuple(blob["change"]),
            tuple(blob["fuse"]),
            tuple(blob["platt"]),
            float(blob["threshold"]),
            float(blob["band"]),
            dict(blob.get("card") or {}),
        )


@dataclass(frozen=True)
class ReferenceDecision:
    """One view's decision with (or without) its reference.

    Attributes:
        label: ``clean`` or ``dirty``.
        p_dirty: calibrated probability of the path that decided.
        uncertain: within the band of the threshold.
        path: ``reference`` (fused with the change map) or ``detector`` (alone).
        reason: why the path: ``aligned`` or a reject reason (:data:`REJECT_REASONS`).
        heat: ``(G, G)`` per-patch dirt probability of the deciding path.
        change_heat: ``(G, G)`` ``sigmoid(change logit)``, zeros without an aligned reference.
        alignment: the alignment, None without a reference.
        detector_p: the detector's own ``p_dirty`` (reported either way).
    """

    label: str
    p_dirty: float
    uncertain: bool
    path: str
    reason: str
    heat: NDArray[np.float32] = field(repr=False)
    change_heat: NDArray[np.float32] = field(repr=False)
    alignment: Alignment | None = field(repr=False)
    detector_p: float

    def as_dict(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "p_dirty": round(self.p_dirty, 6),
            "uncertain": self.uncertain,
            "path": self.path,
            "reason": self.reason,
            "detector_p": round(self.detector_p, 6),
            "heat_max": float(self.heat.max()),
            "change_heat_max": float(self.change_heat.max()),
            "alignment": None if self.alignment is None else self.alignment.as_dict(),
        }


def detector_maps(det: Any, new_work: NDArray[np.uint8]) -> tuple[NDArray[np.float32], NDArray[np.float32], dict]:
    """The detector's head logit map, distance map ``(G, G)`` and its own scores of one work image."""
    import torch

    with torch.inference_mode():
        s, a = det.maps(det.tensor([new_work]))
        sc = det.scores(s, a)
    return s[0].numpy(), a[0].numpy(), sc


def compare(
    ref: ReferenceView,
    new_work: NDArray[np.uint8],
    T_bin_new: NDArray[np.float64],
    width: int,
    height: int,
    tolerance: PoseTolerance | None = None,
) -> tuple[Alignment, NDArray[np.float32] | None]:
    """Align the reference to the new work image and, if aligned, its change features.

    ``tolerance``: a pose delta outside it is rejected (``out_of_tolerance``) before any image work.
    """
    if tolerance is not None and not tolerance.holds(*pose_delta(ref.T_bin_cam, T_bin_new)):
        eye = np.eye(3)
        return Alignment(False, "out_of_tolerance", eye, eye), None
    S = squash_matrix(width, height)
    rh, rw = ref.rgb.shape[:2]
    try:
        H_full = homography_from_poses(ref.K, ref.T_bin_cam, T_bin_new, ref.plane)
    except ClassifierError:
        eye = np.eye(3)
        return Alignment(False, "degenerate_prior", eye, eye), None
    # the reference may come at another resolution: its own squash on the way in
    H0 = S @ H_full @ np.linalg.inv(squash_matrix(rw, rh))
    ref_work = to_work(ref.rgb)
    al = align(ref_work, new_work, H0)
    if not al.ok:
        return al, None
    warped, valid = warp_reference(ref_work, al.H)
    feats, _ = change_features(warped, new_work, valid)
    return al, feats


def decide(
    det: Any,
    fusion: ReferenceFusion | None,
    new_rgb: NDArray[np.uint8],
    T_bin_new: NDArray[np.float64],
    ref: ReferenceView | None,
) -> ReferenceDecision:
    """The per-view decision: fused with the reference when it aligns, else the detector alone.

    Args:
        det: a :class:`~cellctl.classify.fusion.Detector` of the view's surface.
        fusion: the surface's :class:`ReferenceFusion` (None = detector alone).
        new_rgb: (H, W, 3) uint8 view (K of the reference applies at ``ref.rgb``'s size).
        T_bin_new: (4, 4) the view's camera pose in the bin frame.
        ref: the view's reference, None when the plan has none.
    """
    h, w = new_rgb.shape[:2]
    new_work = to_work(new_rgb)
    s, a, sc = detector_maps(det, new_work)
    p_det = float(sc["p"][0])
    zeros = np.zeros_like(s, dtype=np.float32)
    al: Alignment | None = None
    feats = None
    reason = "no_reference"
    if ref is not None and fusion is not None:
        # mirrored content breaks the comparison past the measured pose tolerance (polished steel only)
        tol = MIRROR_POSE_TOLERANCE if fusion.surface == "internal" else None
        al, feats = compare(ref, new_work, T_bin_new, w, h, tol)
        reason = al.reason
    if feats is None or fusion is None:
        return ReferenceDecision(
            "dirty" if p_det >= det.threshold else "clean",
            p_det,
            bool(is_uncertain(p_det, det.threshold, det.band)),
            "detector",
            reason,
            sc["heat"][0],
            zeros,
            al,
            p_det,
        )
    c = fusion.change_logit(feats)
    z = fusion.patch_logit(s, a, c)
    p = fusion.p_image(z)
    return ReferenceDecision(
        "dirty" if p >= fusion.threshold else "clean",
        p,
        bool(is_uncertain(p, fusion.threshold, fusion.band)),
        "reference",
        reason,
        _sig(z).astype(np.float32),
        _sig(c).astype(np.float32),
        al,
        p_det,
    )
