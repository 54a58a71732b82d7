"""Change detection against a reference view: alignment, comparison, fallback (cellctl.classify.reference)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from cellctl.classify.contamination import closeup_steel
from cellctl.classify.reference import (
    Plane,
    ReferenceFusion,
    ReferenceView,
    align,
    change_features,
    decide,
    homography_from_poses,
    plane_from_depth,
    pose_delta,
    to_work,
    warp_reference,
)
from cellctl.errors import ClassifierError
from cellctl.geometry.transforms import look_at, rotation_about, transform_from

SIZE = 128


def _steel(seed: int = 0, surface: str = "external") -> np.ndarray:
    """A textured close-up (brushed, with seams and scratches) at the work size, uint8."""
    rng = np.random.default_rng(seed)
    img = closeup_steel(surface, SIZE, SIZE, rng)
    # brushed grain alone is 1-D; a few soft blobs give ECC a 2-D hold as a seam or a reflection does
    blobs = np.zeros((SIZE, SIZE), np.float32)
    for _ in range(6):
        cv2.circle(blobs, tuple(int(v) for v in rng.uniform(10, SIZE - 10, 2)), int(rng.uniform(5, 15)), 1.0, -1)
    img = img * (1 - 0.3 * cv2.GaussianBlur(blobs, (0, 0), 3)[..., None])
    return np.clip(img * 255 + 0.5, 0, 255).astype(np.uint8)


def _H(shift: tuple[float, float], deg: float, persp: float = 0.0) -> np.ndarray:
    c = SIZE / 2
    T1 = np.array([[1, 0, -c], [0, 1, -c], [0, 0, 1]], float)
    a = math.radians(deg)
    R = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [persp, 0, 1]], float)
    T2 = np.array([[1, 0, c + shift[0]], [0, 1, c + shift[1]], [0, 0, 1]], float)
    return T2 @ R @ T1


def _corner_err(H: np.ndarray, G: np.ndarray) -> float:
    c = np.array([[0, 0, 1], [SIZE, 0, 1], [0, SIZE, 1], [SIZE, SIZE, 1]], float).T
    a, b = H @ c, G @ c
    return float(np.linalg.norm(a[:2] / a[2] - b[:2] / b[2], axis=0).max())


def test_identity_alignment_on_the_same_image() -> None:
    """The same image against itself: aligned, H ≈ I, correlation ≈ 1."""
    img = _steel(1)
    al = align(img, img, np.eye(3))
    assert al.ok and al.reason == "aligned"
    assert _corner_err(al.H, np.eye(3)) < 0.1
    assert al.correlation > 0.999


def test_known_homography_is_recovered_from_a_rough_prior() -> None:
    """A view warped by a known homography (shift, turn, slight perspective): ECC recovers it from
    a prior that is 3 px off, to under half a pixel at the corners."""
    ref = _steel(2)
    G = _H((3.0, -2.0), 2.0, 1e-4)
    new = cv2.warpPerspective(ref, G, (SIZE, SIZE), borderMode=cv2.BORDER_REFLECT)
    prior = _H((0.5, 0.0), 1.0)
    al = align(ref, new, prior)
    assert al.ok, al
    assert _corner_err(al.H, G) < 0.5
    assert _corner_err(prior, G) > 2.5


def test_unrelated_views_are_rejected_with_a_reason() -> None:
    """Another piece of steel is no reference: rejected, and the result says why."""
    al = align(_steel(3), _steel(4, "internal"), np.eye(3))
    assert not al.ok
    assert al.reason in ("low_correlation", "ecc_not_converged", "far_from_prior")


def test_a_prior_far_from_the_image_evidence_is_rejected() -> None:
    """ECC locks onto the true 9 px shift while the pose says −6 px: the 15 px move exceeds the bound."""
    ref = _steel(5)
    G = _H((9.0, 0.0), 0.0)
    new = cv2.warpPerspective(ref, G, (SIZE, SIZE), borderMode=cv2.BORDER_REFLECT)
    al = align(ref, new, _H((-6.0, 0.0), 0.0))
    assert (al.ok, al.reason) == (False, "far_from_prior")
    assert al.correlation > 0.99 and al.prior_shift_px == pytest.approx(15.0, abs=0.5)
    deg = align(ref, new, np.zeros((3, 3)))
    assert not deg.ok and deg.reason == "degenerate_prior"


def test_exposure_and_white_balance_give_no_change() -> None:
    """×1.25 exposure with a (1.08, 0.93, 1.1) white balance, aligned: every patch's change stays small."""
    ref = _steel(6)
    new = np.clip(ref.astype(np.float32) * 1.25 * np.array([1.08, 0.93, 1.1], np.float32), 0, 255).astype(np.uint8)
    warped, valid = warp_reference(ref, np.eye(3))
    feats, cover = change_features(warped, new, valid)
    assert cover.min() > 0.5
    assert feats[0].max() < 0.06  # colour residual, log units
    assert feats[1].max() < 0.15  # structure dissimilarity
    assert feats[2].max() < 0.1  # contrast ratio


def test_a_residual_misregistration_stays_inside_the_envelope() -> None:
    """The reference 1.5 px off (what ECC and a plane homography leave at a wall edge): brushed
    grain, seams and blobs stay inside the ±2 px envelope, no patch shows change."""
    ref = _steel(10)
    warped, valid = warp_reference(ref, _H((1.5, -1.0), 0.3))
    feats, _ = change_features(warped, ref, valid)
    assert feats[0].max() < 0.05 and feats[1].max() < 0.06


def test_a_pasted_blob_gives_change_at_its_patches() -> None:
    """A matte cream blob of 14 px: the strongest colour change lies on the blob's patches."""
    ref = _steel(7)
    new = ref.copy()
    cv2.circle(new, (77, 45), 7, (235, 225, 200), -1)
    warped, valid = warp_reference(ref, np.eye(3))
    feats, _ = change_features(warped, new, valid)
    colour = feats[0]
    iy, ix = np.unravel_index(int(np.argmax(colour)), colour.shape)
    assert abs(ix - 77 / 8) <= 1.5 and abs(iy - 45 / 8) <= 1.5
    far = colour.copy()
    far[max(0, iy - 2) : iy + 3, max(0, ix - 2) : ix + 3] = 0
    assert colour.max() > 0.3 and far.max() < 0.1


def test_pose_homography_maps_plane_points() -> None:
    """H from two poses and the plane maps the plane's projections in one view to the other's."""
    K = np.array([[180.0, 0, 128], [0, 180, 72], [0, 0, 1]])
    T1 = look_at([0.05, -0.4, 0.3], [0, 0, 0], (0, 0, 1))
    T2 = T1 @ transform_from(rotation_about((0.3, 1, 0.2), math.radians(0.5)), [0.01, -0.004, 0.006])
    # the bin-frame plane z = 0 in camera 1's frame
    T1i = np.linalg.inv(T1)
    n = T1i[:3, :3] @ np.array([0, 0, 1.0])
    d = float(n @ T1i[:3, 3])
    H = homography_from_poses(K, T1, T2, Plane(tuple(n), d))
    rng = np.random.default_rng(0)
    P = np.c_[rng.uniform(-0.1, 0.1, (20, 2)), np.zeros(20), np.ones(20)]

    def proj(T: np.ndarray) -> np.ndarray:
        x = (np.linalg.inv(T) @ P.T)[:3]
        u = K @ x
        return u[:2] / u[2]

    u1, u2 = proj(T1), proj(T2)
    v = H @ np.r_[u1, np.ones((1, 20))]
    assert np.abs(v[:2] / v[2] - u2).max() < 1e-6
    mm, deg = pose_delta(T1, T2)
    assert mm == pytest.approx(math.sqrt(0.01**2 + 0.004**2 + 0.006**2) * 1000, rel=1e-6)
    assert deg == pytest.approx(0.5, abs=1e-6)
    # the same plane back from a depth image of it
    h, w = 144, 256
    ys, xs = np.mgrid[0:h, 0:w]
    rays = np.stack([xs, ys, np.ones_like(xs)], -1) @ np.linalg.inv(K).T
    depth = d / (rays @ n)
    pl = plane_from_depth(depth.astype(np.float32), K)
    sign = 1.0 if d > 0 else -1.0  # (n, d) and (-n, -d) are one plane; the fit keeps d > 0
    assert np.allclose(pl.normal, sign * n, atol=1e-4) and pl.distance == pytest.approx(sign * d, rel=1e-4)


class _FakeDetector:
    """The detector's interface: constant maps, its own p_dirty 0.9 (dirty at 0.5)."""

    threshold = 0.5
    band = 1.5
    model_id = "fake"

    def tensor(self, images: list[np.ndarray]) -> torch.Tensor:
        return torch.zeros(len(images), 3, SIZE, SIZE)

    def maps(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return torch.full((len(x), 16, 16), -3.0), torch.full((len(x), 16, 16), 1.0)

    def scores(self, s: torch.Tensor, a: torch.Tensor) -> dict[str, np.ndarray]:
        return {"p": np.full(len(s), 0.9), "heat": np.full((len(s), 16, 16), 0.2, np.float32)}


def _fusion() -> ReferenceFusion:
    return ReferenceFusion("external", (10.0, 3.0, 3.0, -4.0), (1.0, 0.0, 1.0, 0.0, 0.0, 0.0), (1.0, 0.0), 0.5, 1.5)


def test_fusion_falls_back_to_the_detector_without_a_usable_reference() -> None:
    """No reference, or one that does not align: the detector decides alone and says why; an
    aligned clean reference fuses and the change map says nothing changed."""
    det = _FakeDetector()
    img = _steel(8)
    T = look_at([0, -0.4, 0.2], [0, 0, 0], (0, 0, 1))
    plane = Plane((0.0, 0.0, 1.0), 0.4)
    K = np.array([[92.0, 0, 63.5], [0, 92, 63.5], [0, 0, 1]])
    none = decide(det, _fusion(), img, T, None)
    assert (none.path, none.reason, none.label, none.p_dirty) == ("detector", "no_reference", "dirty", 0.9)
    assert none.change_heat.max() == 0
    bad = decide(det, _fusion(), img, T, ReferenceView(_steel(9, "internal"), T, plane, K))
    assert bad.path == "detector" and bad.reason != "aligned" and bad.alignment is not None
    good = decide(det, _fusion(), img, T, ReferenceView(img, T, plane, K))
    assert (good.path, good.reason) == ("reference", "aligned")
    assert good.change_heat.max() < 0.2
    assert good.p_dirty < 0.5 and good.label == "clean"
    assert to_work(img) is img
    # polished steel: a pose 50 mm from the reference's is past the mirror tolerance, no image work
    internal = ReferenceFusion("internal", (10.0, 3.0, 3.0, -4.0), (1.0, 0.0, 1.0, 0.0, 0.0, 0.0), (1.0, 0.0), 0.5, 1.5)
    far = T @ transform_from(np.eye(3), [0.05, 0.0, 0.0])
    out = decide(det, internal, img, far, ReferenceView(img, T, plane, K))
    assert (out.path, out.reason) == ("detector", "out_of_tolerance")


def test_fusion_file_round_trip_and_refusals(tmp_path) -> None:
    """Save/load keeps the weights; a foreign surface or a malformed file is refused with the value."""
    f = _fusion()
    p = tmp_path / "external.reference.json"
    f.save(p)
    g = ReferenceFusion.load(p, "external")
    assert g.change == f.change and g.fuse == f.fuse and g.threshold == f.threshold
    with pytest.raises(ClassifierError, match="'external', expected 'internal'"):
        ReferenceFusion.load(p, "internal")
    p.write_text('{"format": "cellctl-reference-fusion/2", "surface": "external", "change": [1]}')
    with pytest.raises(ClassifierError, match="malformed"):
        ReferenceFusion.load(p)


def test_plane_from_the_mesh_matches_the_plane_of_a_rendered_depth() -> None:
    """A twin view of an external wall: the mesh's plane (no depth stored) agrees with the plane
    fitted to the render's depth, and the two give the same homography to within a pixel."""
    from cellctl.classify.heatmap import MeshCaster
    from cellctl.classify.reference import plane_from_mesh
    from cellctl.config import load_config
    from cellctl.geometry.camera import D435_COLOR
    from cellctl.geometry.catalog import load_catalog
    from cellctl.sim.render import SimRenderer

    cfg = load_config()
    cat = load_catalog(cfg.path(cfg.catalog), cfg.root)
    name = "case_study"
    mesh = cat.load_mesh(name)
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    target = np.array([0.0, lo[1], 0.5 * (lo[2] + hi[2])])  # the middle of the -y side wall
    T = look_at(target + [0.1, -0.45, 0.05], target, (0, 0, 1))
    intr = D435_COLOR.scaled(256 / D435_COLOR.width)
    out = SimRenderer(cat).render_bin_view(name, T, intr, dirty=False)
    K = intr.K()
    a = plane_from_depth(out.depth, K)
    b = plane_from_mesh(MeshCaster(mesh), mesh, T, K, intr.width, intr.height)
    assert np.dot(a.normal, b.normal) > 0.999 and b.distance == pytest.approx(a.distance, abs=0.005)
    # the stored form: poses in the robot base frame, the bin parked anywhere
    from cellctl.classify.reference import reference_view

    T_base_bin = transform_from(rotation_about((0, 0, 1), 0.7), [1.2, -0.3, 0.1])
    rv = reference_view(out.rgb, T_base_bin @ T, T_base_bin, K, MeshCaster(mesh), mesh)
    assert np.allclose(rv.T_bin_cam, T) and rv.plane.distance == pytest.approx(b.distance, abs=1e-9)
    T2 = T @ transform_from(rotation_about((0, 1, 0), math.radians(0.5)), [0.01, 0.0, 0.0])
    ha, hb = homography_from_poses(K, T, T2, a), homography_from_poses(K, T, T2, b)
    c = np.array([[64.0, 36, 1], [192, 108, 1]]).T
    pa, pb = ha @ c, hb @ c
    assert np.abs(pa[:2] / pa[2] - pb[:2] / pb[2]).max() < 1.0
