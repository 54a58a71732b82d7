"""solve_hand_eye(): Park–Martin recovers a known T_flange_cam (synthetic and rendered views)."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.errors import CellError
from cellctl.geometry.transforms import (
    invert,
    look_at,
    pose_error,
    rotation_about,
    transform_from,
    transform_from_xyz_rpy,
)
from cellctl.vision import identify, solve_hand_eye
from cellctl.vision.handeye import log_rotation
from cellctl.vision.render import render_boards

from .scenes import INTR, SPEC_A

# A D435 on a bracket: 6 cm off-axis, 9 cm forward, optical axis along the tool axis, rolled 90°.
X_TRUE = transform_from_xyz_rpy((0.06, -0.015, 0.09), (0.02, -0.03, np.pi / 2))
T_BASE_BOARD = transform_from_xyz_rpy((1.1, 0.2, 0.5), (-np.pi / 2, 0.0, np.pi / 2))


def _arm_poses(n: int, rng: np.random.Generator, distance: float = 0.7) -> list[np.ndarray]:
    """Flange poses whose camera looks at the board centre from a spherical cap."""
    c = T_BASE_BOARD[:3, :3] @ np.array([0.21, 0.15, 0.0]) + T_BASE_BOARD[:3, 3]
    normal = -T_BASE_BOARD[:3, 2]  # towards the camera side of the board
    out = []
    for _ in range(n):
        d = normal + rng.normal(0, 0.35, 3)
        d /= np.linalg.norm(d)
        T_base_cam = look_at(c + distance * d, c, roll_rad=rng.uniform(-0.5, 0.5))
        out.append(T_base_cam @ invert(X_TRUE))
    return out


def test_log_rotation_round_trip() -> None:
    for axis, ang in [((1, 0, 0), 0.0), ((0, 1, 1), 1.0), ((1, 2, 3), np.pi - 1e-8), ((0, 0, 1), np.pi)]:
        w = log_rotation(rotation_about(axis, ang))
        assert np.linalg.norm(w) == pytest.approx(ang, abs=1e-6)
        if ang > 0:
            np.testing.assert_allclose(rotation_about(w, np.linalg.norm(w)), rotation_about(axis, ang), atol=1e-6)


def test_exact_recovery_noise_free() -> None:
    F = _arm_poses(6, np.random.default_rng(0))
    C = [invert(f @ X_TRUE) @ T_BASE_BOARD for f in F]
    res = solve_hand_eye(F, C)
    dt, dr = pose_error(res.T_flange_cam, X_TRUE)
    assert dt < 1e-9 and dr < 1e-9
    assert max(res.residual_mm) < 1e-6
    np.testing.assert_allclose(res.T_base_board, T_BASE_BOARD, atol=1e-9)


def test_recovery_from_rendered_views(catalog) -> None:
    """The whole chain: render what the camera sees, identify the board, solve → < 1 mm / 0.1°."""
    rng = np.random.default_rng(5)
    F = _arm_poses(10, rng)
    C = []
    for f in F:
        T_cam_board = invert(f @ X_TRUE) @ T_BASE_BOARD
        img = render_boards([(SPEC_A, T_cam_board)], INTR, rng=rng)
        C.append(identify(img, INTR, None, catalog).T_cam_board)
    res = solve_hand_eye(F, C)
    dt, dr = pose_error(res.T_flange_cam, X_TRUE)
    assert dt * 1000 < 1.0, f"translation error {dt * 1000:.3f} mm"
    assert np.degrees(dr) < 0.1, f"rotation error {np.degrees(dr):.4f} deg"
    assert res.axis_spread_deg > 45
    d = res.to_dict()
    assert d["n_views"] == 10 and d["residual_mm"]["rms"] < 1.0


def test_degenerate_inputs() -> None:
    F = _arm_poses(4, np.random.default_rng(1))
    C = [invert(f @ X_TRUE) @ T_BASE_BOARD for f in F]
    with pytest.raises(CellError, match="at least 3 views, got 2"):
        solve_hand_eye(F[:2], C[:2])
    with pytest.raises(CellError, match="got 4 robot poses and 3 board poses"):
        solve_hand_eye(F, C[:3])
    # Rotations about one axis only (the base z axis): the rotation about it is unobservable.
    F1 = [transform_from(rotation_about((0, 0, 1), a), [0.5 + 0.1 * a, 0.1, 0.6]) for a in (0.0, 0.3, 0.6, 0.9)]
    C1 = [invert(f @ X_TRUE) @ T_BASE_BOARD for f in F1]
    with pytest.raises(CellError, match="share one axis"):
        solve_hand_eye(F1, C1)
    # Pure translations: nothing about the rotation.
    F2 = [transform_from(np.eye(3), [0.5 + 0.05 * k, 0.1, 0.6]) for k in range(4)]
    C2 = [invert(f @ X_TRUE) @ T_BASE_BOARD for f in F2]
    with pytest.raises(CellError, match="rotate by ≥ 2°"):
        solve_hand_eye(F2, C2)
