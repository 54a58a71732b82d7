"""cellctl.motion: joint path → trajectory within the UR10e velocity and acceleration limits."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.errors import RobotError
from cellctl.motion import UR10E, UR10E_JOINT_ACCEL, JointLimits, time_parametrize
from cellctl.workers.robot.ur import path_deviation


def _path(seed: int = 0, k: int = 4) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.uniform(-1.2, 1.2, (k, 6)), axis=0)


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("fraction", [0.25, 1.0])
def test_samples_stay_within_velocity_and_acceleration_limits(seed: int, fraction: float) -> None:
    path = _path(seed)
    tr = time_parametrize(path, UR10E, speed_fraction=fraction)
    t, Q, QD = tr.sample(1000.0)
    vmax = UR10E.velocity * fraction
    assert (np.abs(QD) <= vmax * (1 + 1e-9) + 1e-12).all()
    acc = np.abs(np.diff(QD, axis=0)) / np.diff(t)[:, None]
    assert (acc <= UR10E_JOINT_ACCEL * (1 + 1e-6) + 1e-9).all()
    # the slowest-limited joint actually reaches a limit: time-optimal, not just slow
    assert np.isclose((np.abs(QD) / vmax).max(), 1.0, atol=1e-3) or np.isclose((acc / UR10E_JOINT_ACCEL).max(), 1, 1e-3)
    assert np.allclose(Q[0], path[0]) and np.allclose(Q[-1], path[-1], atol=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_motion_stays_on_the_checked_straight_segments(seed: int) -> None:
    path = _path(seed)
    _, Q, _ = time_parametrize(path).sample(200.0)
    assert max(path_deviation(path, q) for q in Q) < 1e-9
    # …and passes every waypoint at rest (stop at each, like movej with blend 0)
    tr = time_parametrize(path)
    for s in tr.segments:
        assert np.allclose(tr.at(s.t0)[1], 0.0, atol=1e-9)


def test_duration_is_the_trapezoid_of_the_tightest_joint() -> None:
    q1 = np.array([1.0, 0.5, 0.2, 0.0, 0.0, -1.0])
    tr = time_parametrize([np.zeros(6), q1], UR10E, speed_fraction=0.5)
    v, a = UR10E.velocity[0] * 0.5, UR10E_JOINT_ACCEL[0]  # joint 0 limits (1 rad at its own limits)
    assert tr.duration == pytest.approx(1.0 / v + v / a, rel=1e-6)
    (entry,) = tr.movej_path()
    assert entry[:6] == pytest.approx(q1.tolist()) and entry[6] == pytest.approx(v) and entry[7] == pytest.approx(a)
    assert entry[8] == 0.0


def test_speed_fraction_slows_the_motion_and_zero_length_moves_take_no_time() -> None:
    path = 3 * _path(1, 2)  # long enough to cruise
    slow, fast = (time_parametrize(path, speed_fraction=f).duration for f in (0.2, 0.8))
    assert slow > 1.5 * fast
    still = time_parametrize([path[0], path[0]])
    assert still.duration == 0.0 and still.movej_path() == []


@pytest.mark.parametrize(
    ("path", "kw", "match"),
    [
        (np.zeros((3, 5)), {}, r"shape \(3, 5\); expected \(K, 6\)"),
        ([[0, 0, 0, 0, 0, np.nan], [0] * 6], {}, "NaN"),
        (np.zeros((2, 6)), {"speed_fraction": 0.0}, r"speed_fraction is 0.0; expected a number in \(0, 1\]"),
        (np.zeros((2, 6)), {"accel_fraction": 1.5}, r"accel_fraction is 1.5"),
    ],
)
def test_bad_input_is_refused_naming_the_value(path, kw, match) -> None:
    with pytest.raises(RobotError, match=match):
        time_parametrize(path, **kw)


def test_sample_rate_must_be_positive() -> None:
    with pytest.raises(RobotError, match="sample rate is -1"):
        time_parametrize(_path()).sample(-1)


def test_custom_limits_bind() -> None:
    lim = JointLimits(np.full(6, 0.1), np.full(6, 0.1))
    tr = time_parametrize([np.zeros(6), np.full(6, 1.0)], lim, 1.0)
    assert tr.duration == pytest.approx(1.0 / 0.1 + 0.1 / 0.1)


def test_arm_fractions_are_the_backends_own() -> None:
    from cellctl.config import CellConfig
    from cellctl.motion import arm_fractions

    cfg = CellConfig()
    assert arm_fractions(cfg.robot) == (cfg.robot.speed_fraction, 1.0)  # the sim arm: full accelerations
    ur = cfg.robot.model_copy(update={"backend": "ur", "ur": cfg.robot.ur.model_copy(update={"accel_fraction": 0.4})})
    assert arm_fractions(ur) == (cfg.robot.speed_fraction, 0.4)
