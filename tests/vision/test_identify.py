"""identify(): bin type and pose from synthetic renders, and every way it refuses."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cellctl.errors import IdentificationError
from cellctl.geometry.catalog import BoardSpec
from cellctl.geometry.transforms import invert, pose_error, transform_from_xyz_rpy
from cellctl.messages import Intrinsics
from cellctl.vision import IdentifySettings, identify
from cellctl.vision.board import board_centre
from cellctl.vision.render import RenderSettings, board_outline, project, render_boards, view_of_board

from .scenes import INTR, SPEC_A, SPEC_B, SPEC_FOREIGN

T_BASE_CAM = transform_from_xyz_rpy((0.4, -0.2, 0.9), (-np.pi / 2, 0.1, -0.3))


def _centre_error_mm(T_true: np.ndarray, T_est: np.ndarray, spec: BoardSpec) -> float:
    c = board_centre(spec)
    return float(np.linalg.norm((T_true[:3, :3] @ c + T_true[:3, 3]) - (T_est[:3, :3] @ c + T_est[:3, 3])) * 1000)


@pytest.mark.parametrize(
    ("distance", "tilt", "max_mm", "max_deg"),
    [(0.5, 35.0, 0.5, 0.1), (1.0, 25.0, 1.0, 0.15), (2.0, 30.0, 3.0, 0.3)],
)
def test_identifies_type_and_pose(catalog, distance, tilt, max_mm, max_deg) -> None:
    rng = np.random.default_rng(7)
    T_cam_board = view_of_board(SPEC_B, INTR, distance, tilt, 60.0, roll_deg=5.0, offset_px=(80.0, -40.0))
    img = render_boards([(SPEC_B, T_cam_board)], INTR, rng=rng)
    ident = identify(img, INTR, T_BASE_CAM, catalog)
    assert ident.bin_type == "bin_b"
    assert ident.marker_ids == list(range(17, 34))
    assert ident.n_corners == 24 and ident.image_points.shape == (24, 2)
    assert _centre_error_mm(T_cam_board, ident.T_cam_board, SPEC_B) < max_mm
    assert np.degrees(pose_error(T_cam_board, ident.T_cam_board)[1]) < max_deg
    # The chain T_base_bin = T_base_cam · T_cam_board · T_board_bin, against ground truth.
    T_true = T_BASE_CAM @ T_cam_board @ invert(SPEC_B.T_bin_board)
    dt, dr = pose_error(T_true, ident.T_base_bin)
    lever = np.linalg.norm(invert(SPEC_B.T_bin_board)[:3, 3] - board_centre(SPEC_B))
    assert dt * 1000 < max_mm + np.radians(max_deg) * lever * 1000
    assert np.degrees(dr) < max_deg
    assert ident.reproj_rms_px < 0.5
    assert ident.ambiguity_ratio < 0.5
    assert abs(ident.distance_m - distance) < 0.01
    assert 0 < ident.sigma_trans_mm < 5 and 0 < ident.sigma_rot_deg < 1
    d = ident.to_dict()
    assert d["bin_type"] == "bin_b" and len(d["T_base_bin"]["orientation"]) == 4


def test_identity_camera_pose_gives_camera_frame(catalog) -> None:
    T = view_of_board(SPEC_A, INTR, 0.8, 20.0, 10.0)
    img = render_boards([(SPEC_A, T)], INTR, rng=np.random.default_rng(1))
    ident = identify(img, INTR, None, catalog)
    assert ident.bin_type == "bin_a"
    np.testing.assert_allclose(ident.T_base_bin, ident.T_cam_board @ invert(SPEC_A.T_bin_board), atol=1e-12)


def test_works_with_the_twin_catalog() -> None:
    """The catalog object of cellctl.geometry.catalog plugs in unchanged."""
    from cellctl.geometry import catalog as catalog_mod

    T_bin_board = transform_from_xyz_rpy((-0.21, -0.4, -0.15), (np.pi / 2, 0.0, 0.0))
    types = [
        catalog_mod.BinType(
            name=name,
            mesh=f"models/bins/{name}.ply",
            mesh_sha256="0" * 64,
            height_m=1.0,
            top_hole_radius_m=0.25,
            board=catalog_mod.BoardSpec(
                squares_x=7,
                squares_y=5,
                square_m=0.06,
                marker_m=0.045,
                first_id=first,
                T_bin_board=T_bin_board.tolist(),
            ),
        )
        for name, first in (("small", 0), ("large", 17))
    ]
    cat = catalog_mod.Catalog(types, root=".")
    spec = types[1].board
    T = view_of_board(spec, INTR, 1.0, 25.0, 100.0)
    ident = identify(render_boards([(spec, T)], INTR, rng=np.random.default_rng(2)), INTR, None, cat)
    assert ident.bin_type == "large"
    assert _centre_error_mm(T, ident.T_cam_board, spec) < 1.0


def _reason(img: np.ndarray, catalog, intr: Intrinsics = INTR, **kw) -> IdentificationError:
    with pytest.raises(IdentificationError) as info:
        identify(img, intr, None, catalog, **kw)
    return info.value


def test_no_markers_blank(catalog) -> None:
    err = _reason(np.full((720, 1280, 3), 128, np.uint8), catalog)
    assert err.code == "no markers"
    assert str(err).startswith("no markers detected") and "blurred?" in str(err)


def test_no_markers_overexposed(catalog) -> None:
    T = view_of_board(SPEC_A, INTR, 1.0, 20.0, 0.0)
    img = render_boards([(SPEC_A, T)], INTR, RenderSettings(exposure=12.0), np.random.default_rng(3))
    err = _reason(img, catalog)
    assert err.code in ("no markers", "too few markers") and "overexposed?" in str(err)


def test_no_markers_motion_blur(catalog) -> None:
    T = view_of_board(SPEC_A, INTR, 1.0, 20.0, 0.0)
    img = render_boards([(SPEC_A, T)], INTR, RenderSettings(motion_blur_px=20.0), np.random.default_rng(3))
    assert _reason(img, catalog).code == "no markers"


def test_two_boards(catalog) -> None:
    Ta = view_of_board(SPEC_A, INTR, 1.3, 10.0, 0.0, offset_px=(-300.0, 0.0))
    Tb = view_of_board(SPEC_B, INTR, 1.3, 10.0, 0.0, offset_px=(300.0, 0.0))
    err = _reason(render_boards([(SPEC_A, Ta), (SPEC_B, Tb)], INTR, rng=np.random.default_rng(4)), catalog)
    assert err.code == "two boards"
    assert "markers from two boards" in str(err) and "bin_a: ids [0, 1," in str(err) and "bin_b: ids [17," in str(err)


def test_unknown_id_range(catalog) -> None:
    T = view_of_board(SPEC_FOREIGN, INTR, 1.0, 20.0, 0.0)
    err = _reason(render_boards([(SPEC_FOREIGN, T)], INTR, rng=np.random.default_rng(5)), catalog)
    assert err.code == "unknown id range"
    assert "unknown id range: ids [500, 501," in str(err) and "bin_a 0..16" in str(err)


def _occlude_all_but(img: np.ndarray, spec: BoardSpec, T: np.ndarray, x0, y0, x1, y1) -> np.ndarray:
    """Grey out the board except the rectangle [x0, x1] × [y0, y1] (in squares)."""
    out = img.copy()
    mask = np.zeros(img.shape[:2], np.uint8)
    cv2.fillConvexPoly(mask, np.rint(project(INTR, T, board_outline(spec, 0.6))).astype(np.int32), 1)
    keep = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]]) * spec.square_m
    cv2.fillConvexPoly(mask, np.rint(project(INTR, T, keep)).astype(np.int32), 0)
    out[mask > 0] = 115
    return out


def test_partial_board_too_few_corners(catalog) -> None:
    T = view_of_board(SPEC_A, INTR, 1.0, 20.0, 30.0)
    img = _occlude_all_but(
        render_boards([(SPEC_A, T)], INTR, rng=np.random.default_rng(6)), SPEC_A, T, -0.5, -0.5, 3.0, 3.0
    )
    err = _reason(img, catalog)
    assert err.code == "too few corners"
    assert str(err).startswith("only 4 corners (need ≥ 6)")


def test_collinear_corners(catalog) -> None:
    T = view_of_board(SPEC_A, INTR, 1.0, 20.0, 30.0)
    img = _occlude_all_but(
        render_boards([(SPEC_A, T)], INTR, rng=np.random.default_rng(6)), SPEC_A, T, -0.5, -0.5, 7.5, 2.0
    )
    err = _reason(img, catalog)
    assert err.code == "collinear"
    assert str(err).startswith("collinear corners: ids [0, 1, 2, 3, 4, 5]")


def test_ambiguous_small_far_board() -> None:
    """A 28 cm board seen almost head-on from 2.2 m: IPPE's two solutions fit equally well."""
    small = BoardSpec(squares_x=7, squares_y=5, square_m=0.04, marker_m=0.03, first_id=0, T_bin_board=np.eye(4))
    rng = np.random.default_rng(12)
    T = view_of_board(small, INTR, 2.2, float(rng.uniform(0, 10)), float(rng.uniform(0, 360)))
    err = _reason(render_boards([(small, T)], INTR, rng=rng), {"small": small})
    assert err.code == "ambiguous"
    assert str(err).startswith("ambiguous IPPE solution ratio 0.9")


def test_reprojection_threshold(catalog) -> None:
    T = view_of_board(SPEC_A, INTR, 1.0, 20.0, 30.0)
    img = render_boards([(SPEC_A, T)], INTR, rng=np.random.default_rng(8))
    err = _reason(img, catalog, settings=IdentifySettings(max_reproj_px=0.01))
    assert err.code == "reprojection" and "> 0.01 px" in str(err)


def test_bad_images(catalog) -> None:
    assert "is 640×480 px but the intrinsics are for 1280×720" in str(
        _reason(np.zeros((480, 640, 3), np.uint8), catalog)
    )
    assert "dtype float32" in str(_reason(np.zeros((720, 1280), np.float32), catalog))
    assert "numpy array" in str(_reason(b"png bytes", catalog))


def test_bad_camera_pose(catalog) -> None:
    T = view_of_board(SPEC_A, INTR, 1.0, 20.0, 30.0)
    img = render_boards([(SPEC_A, T)], INTR, rng=np.random.default_rng(8))
    from cellctl.errors import CellError

    with pytest.raises(CellError, match="T_base_cam rotation part is not a proper rotation"):
        identify(img, INTR, np.diag([1.0, 1.0, -1.0, 1.0]), catalog)


def test_lens_distortion_is_modelled(catalog) -> None:
    """A distorted image identified with its distortion coefficients gives the true pose."""
    dist = [-0.12, 0.08, 0.0005, -0.0004, 0.0]
    intr_d = INTR.model_copy(update={"dist": dist})
    T = view_of_board(SPEC_A, INTR, 0.8, 25.0, 200.0, offset_px=(250.0, 120.0))
    ideal = render_boards([(SPEC_A, T)], INTR, rng=np.random.default_rng(9))
    # Distort: each pixel of the distorted image samples the ideal image at its undistorted position.
    h, w = ideal.shape[:2]
    uv = np.stack(np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32)), -1).reshape(-1, 1, 2)
    und = cv2.undistortPoints(uv, INTR.K(), np.array(dist), P=INTR.K()).reshape(h, w, 2)
    img = cv2.remap(ideal, und[..., 0], und[..., 1], cv2.INTER_LINEAR)
    good = identify(img, intr_d, None, catalog)
    assert _centre_error_mm(T, good.T_cam_board, SPEC_A) < 1.0
    assert np.degrees(pose_error(T, good.T_cam_board)[1]) < 0.2
    assert good.reproj_rms_px < 0.5
    # Ignoring the distortion costs accuracy: the same image without it is worse.
    bad = identify(img, INTR, None, catalog, settings=IdentifySettings(max_reproj_px=10.0))
    assert bad.reproj_rms_px > 2 * good.reproj_rms_px
