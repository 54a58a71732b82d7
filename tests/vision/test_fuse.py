"""fuse(): several views of one bin → a better pose, residuals and an uncertainty figure."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.errors import IdentificationError
from cellctl.geometry.transforms import invert, pose_error, transform_from, transform_from_xyz_rpy
from cellctl.vision import fuse, identify
from cellctl.vision.board import board_centre
from cellctl.vision.render import render_boards, view_of_board

from .scenes import INTR, SPEC_A, SPEC_B

# The board stands still in the robot base frame; the camera observes it from several poses.
T_BASE_BOARD = transform_from_xyz_rpy((1.2, 0.3, 0.6), (-np.pi / 2, 0.0, np.pi / 2))


def _views(n: int, distance: float, seed: int, spec=SPEC_A):
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        T_cam_board = view_of_board(
            spec,
            INTR,
            distance,
            25.0 + 5 * rng.uniform(),
            360.0 * k / n + rng.uniform(0, 30),
            roll_deg=rng.uniform(-10, 10),
        )
        T_base_cam = T_BASE_BOARD @ invert(T_cam_board)
        img = render_boards([(spec, T_cam_board)], INTR, rng=rng)
        out.append((img, T_base_cam))
    return out


def _centre_err_mm(T_base_bin: np.ndarray) -> float:
    c = board_centre(SPEC_A)
    T = T_base_bin @ SPEC_A.T_bin_board
    return float(np.linalg.norm(T[:3, :3] @ c + T[:3, 3] - (T_BASE_BOARD[:3, :3] @ c + T_BASE_BOARD[:3, 3])) * 1000)


def test_fusion_reduces_error(catalog) -> None:
    truth = T_BASE_BOARD @ invert(SPEC_A.T_bin_board)
    single_t, single_r = [], []
    fused_t, fused_r = [], []
    for seed in range(3):
        idents = [identify(img, INTR, T, catalog) for img, T in _views(4, 2.0, seed)]
        single_t += [_centre_err_mm(i.T_base_bin) for i in idents]
        single_r += [np.degrees(pose_error(truth, i.T_base_bin)[1]) for i in idents]
        f = fuse(idents)
        assert f.bin_type == "bin_a" and f.used == [0, 1, 2, 3] and f.rejected == []
        assert len(f.residual_mm) == 4 and len(f.residual_deg) == 4
        fused_t.append(_centre_err_mm(f.T_base_bin))
        fused_r.append(np.degrees(pose_error(truth, f.T_base_bin)[1]))
        # The uncertainty figure is honest: the actual error is within 3 σ.
        assert fused_t[-1] < 3 * f.sigma_trans_mm + 0.1
        assert f.sigma_bin_origin_mm >= f.sigma_trans_mm
    assert np.mean(fused_t) < 0.7 * np.mean(single_t)
    assert np.mean(fused_r) < np.mean(single_r)


def test_outlier_view_is_rejected(catalog) -> None:
    views = _views(4, 1.0, 11)
    idents = [identify(img, INTR, T, catalog) for img, T in views]
    # One view with a bad robot pose (3 cm off, as after a missed FK update).
    img, T = views[2]
    bad = transform_from(T[:3, :3], T[:3, 3] + [0.03, 0.0, 0.0])
    idents[2] = identify(img, INTR, bad, catalog)
    f = fuse(idents)
    assert f.rejected == [2] and f.used == [0, 1, 3]
    assert f.residual_mm[2] > 25.0
    assert _centre_err_mm(f.T_base_bin) < 1.0


def test_single_view_passes_through(catalog) -> None:
    ((img, T),) = _views(1, 1.0, 3)
    ident = identify(img, INTR, T, catalog)
    f = fuse([ident])
    np.testing.assert_allclose(f.T_base_bin, ident.T_base_bin, atol=1e-9)
    assert f.to_dict()["n_views"] == 1


def test_fuse_refuses_empty_and_mixed(catalog) -> None:
    with pytest.raises(IdentificationError, match="got 0 identifications"):
        fuse([])
    ((ia, Ta),) = _views(1, 1.0, 4)
    ((ib, Tb),) = _views(1, 1.0, 4, spec=SPEC_B)
    with pytest.raises(IdentificationError, match=r"views disagree on the bin type: \['bin_a', 'bin_b'\]"):
        fuse([identify(ia, INTR, Ta, catalog), identify(ib, INTR, Tb, catalog)])
