"""UR10e model: FK against ur-analytic-ik, IK/FK round trip, limits, hand-eye, refusals."""

from __future__ import annotations

import numpy as np
import pytest
from ur_analytic_ik import ur10e

from cellctl.errors import RobotError
from cellctl.geometry import robot_model as rm
from cellctl.geometry.transforms import pose_error


def _random_q(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.uniform(-np.pi, np.pi, (n, 6))
    return q


def test_batch_fk_matches_ur_analytic_ik() -> None:
    rng = np.random.default_rng(0)
    Q = _random_q(rng, 100)
    F = rm.fk_batch(Q)
    for q, T in zip(Q, F, strict=True):
        assert np.abs(T - ur10e.forward_kinematics(*q)).max() < 1e-12


def test_ik_fk_round_trip_below_a_micrometre() -> None:
    """Every IK solution of 300 random reachable poses maps back to the pose within 1e-6 m / 1e-6 rad."""
    rng = np.random.default_rng(1)
    Q = _random_q(rng, 300)
    worst_t = worst_r = 0.0
    n_sols = 0
    for q in Q:
        T = rm.fk(q)
        sols = rm.ik(T, q)
        assert len(sols) >= 1
        n_sols += len(sols)
        assert np.abs(sols[0] - q).max() < 1e-6  # the generating configuration is found and ranked first
        for s in sols:
            dt, dr = pose_error(rm.fk(s), T)
            worst_t, worst_r = max(worst_t, dt), max(worst_r, dr)
    assert worst_t < 1e-6 and worst_r < 1e-6
    assert n_sols / len(Q) > 4


def test_camera_ik_puts_the_optical_frame_on_target() -> None:
    rng = np.random.default_rng(2)
    for q in _random_q(rng, 20):
        T = rm.camera_pose(q)
        for s in rm.ik_camera(T, q):
            dt, dr = pose_error(rm.camera_pose(s), T)
            assert dt < 1e-6 and dr < 1e-6


def test_hand_eye_is_the_papers_opt_H_cam() -> None:
    assert np.allclose(rm.T_FLANGE_CAM, [[1, 0, 0, 0.118], [0, 1, 0, 0.058], [0, 0, 1, -0.035], [0, 0, 0, 1]])


def test_unreachable_pose_has_no_solution_and_a_reason() -> None:
    T = np.eye(4)
    T[:3, 3] = [2.5, 0.0, 0.3]
    assert len(rm.ik_camera(T)) == 0
    assert "beyond the arm's" in rm.unreachable_reason(T)


def test_joint_limits_are_enforced_with_the_joint_named() -> None:
    with pytest.raises(RobotError, match=r"joint elbow = 3.5000 rad is outside its limits \[-3.1416, 3.1416\]"):
        rm.check_joints([0, 0, 3.5, 0, 0, 0])
    with pytest.raises(RobotError, match="6 finite joint angles"):
        rm.check_joints([0, 0, 0])
    for s in rm.ik(rm.fk([0.3, -1.0, 1.0, -1.0, 1.0, 0.2])):
        rm.check_joints(s)


def test_wrap_near_picks_the_closest_equivalent_angle() -> None:
    q = np.array([3.0, 0, 0, 0, 0, -3.0])
    w = rm.wrap_near(q, np.array([-3.0, 0, 0, 0, 0, 3.0]))
    assert w[0] == pytest.approx(3.0 - 2 * np.pi) and w[5] == pytest.approx(-3.0 + 2 * np.pi)


def test_ik_prints_nothing_on_stdout(capfd: pytest.CaptureFixture[str]) -> None:
    """ur-analytic-ik warns on stdout near singularities; cellctl keeps stdout clean (bench JSON)."""
    rng = np.random.default_rng(3)
    for q in _random_q(rng, 200):
        rm.ik(rm.fk(q))
    assert capfd.readouterr().out == ""
