"""Joint path → trajectory (ruckig, one profile of the path parameter per straight segment).

Why ruckig and not toppra: the paths come from :func:`cellctl.sim.motion.plan_path`, whose
*straight joint-space segments* are what was collision-checked. toppra parametrises a smooth
spline through the waypoints, which leaves those segments between waypoints (the spline is not
the checked path). A 1-DOF ruckig profile of the path parameter s ∈ [0, 1], rest to rest, with
the limits of the tightest joint (``min_j v_j / |Δq_j|``, ``min_j a_j / |Δq_j|``) keeps every joint
proportional along a segment, i.e. it moves exactly on the checked straight line, time-optimally
within per-joint velocity and acceleration limits (a phase-synchronised 6-DOF profile does not
exist when the joints' velocity/acceleration ratios differ, and ruckig then leaves the line). The cost is a stop at each
interior waypoint; shortcut RRT paths have few (2–5), and it is also what the UR controller does
for ``movej`` with blend radius 0, so the sim arm and the real arm run the same profile.

``jerk`` is infinite by default (second-order, trapezoidal profiles): the UR's ``movej`` is
trapezoidal in the leading axis, so this is the profile the controller itself executes; a finite
jerk gives S-curves (for servo streaming), at a slightly longer duration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from ruckig import InputParameter, Result, Ruckig
from ruckig import Trajectory as _RuckigTrajectory

from cellctl.errors import RobotError
from cellctl.geometry import robot_model as rm

__all__ = [
    "UR10E",
    "UR10E_JOINT_ACCEL",
    "UR10E_JOINT_ACCEL_CEILING",
    "JointLimits",
    "Segment",
    "Trajectory",
    "arm_fractions",
    "time_parametrize",
]

UR10E_JOINT_ACCEL = np.full(6, 5.0)
"""Nominal joint accelerations (rad/s²), every joint. UR publishes no per-joint acceleration
limit (the joints are torque-limited; what a joint can do depends on payload and pose). 5 rad/s²
is what Universal Robots' own ROS 2 driver gives MoveIt for time parametrisation of every UR
model (``ur_moveit_config/config/joint_limits.yaml``: "chosen conservatively to work in most use
cases"); our payload is a camera of under 1 kg against the UR10e's 12.5 kg. It replaced URScript's
``movej`` default of 1.4 rad/s² (a program default, not a limit), at which most inspection moves
were acceleration-bound (speed fraction 0.5 → 1.0 shortened the tours' motion by only 9 %).
``robot.ur.accel_fraction`` scales it down for a cell that needs gentler motion."""

UR10E_JOINT_ACCEL_CEILING = 40.0
"""The most a ``movej``/``stopj`` may ask for (rad/s²): PolyScope's 2291 °/s² Move maximum, the
bound ur_rtde also enforces (``UR_JOINT_ACCELERATION_MAX``)."""


@dataclass(frozen=True)
class JointLimits:
    """Per-joint velocity (rad/s) and acceleration (rad/s²) limits, shape (6,) each."""

    velocity: NDArray[np.float64]
    acceleration: NDArray[np.float64]
    jerk: float = math.inf

    def scaled(self, speed_fraction: float, accel_fraction: float = 1.0) -> JointLimits:
        """These limits × fractions in (0, 1].

        Raises:
            RobotError: a fraction outside (0, 1].
        """
        for name, f in (("speed_fraction", speed_fraction), ("accel_fraction", accel_fraction)):
            if not (0.0 < f <= 1.0) or not math.isfinite(f):
                raise RobotError(f"{name} is {f!r}; expected a number in (0, 1]")
        return JointLimits(self.velocity * speed_fraction, self.acceleration * accel_fraction, self.jerk)


UR10E = JointLimits(np.asarray(rm.MAX_JOINT_SPEED, dtype=np.float64), UR10E_JOINT_ACCEL)
"""The UR10e's joint speed limits (120/120/180/180/180/180 °/s) and :data:`UR10E_JOINT_ACCEL`."""


def arm_fractions(robot_cfg: Any) -> tuple[float, float]:
    """``(speed_fraction, accel_fraction)`` of :data:`UR10E` the configured arm moves with.

    ``robot_cfg`` is the config's ``robot`` section: ``speed_fraction`` on every backend; the UR
    backend also applies ``robot.ur.accel_fraction``, the sim arm the full accelerations (as
    the robot workers' own ``_accel_fraction``). The one place planners and benches take the
    motion limits from, so a modelled cycle moves as the arm will.
    """
    accel = float(robot_cfg.ur.accel_fraction) if robot_cfg.backend == "ur" else 1.0
    return float(robot_cfg.speed_fraction), accel


@dataclass(frozen=True)
class Segment:
    """One straight joint-space segment, rest to rest."""

    q0: NDArray[np.float64]
    q1: NDArray[np.float64]
    t0: float
    duration: float
    lead_speed: float
    """Peak speed (rad/s) of the leading (largest-displacement) joint: ``movej``'s ``v``."""
    lead_accel: float
    """Acceleration (rad/s²) of the leading joint: ``movej``'s ``a``."""
    _profile: _RuckigTrajectory | None = field(default=None, repr=False, compare=False)

    def at(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Position and velocity at ``t`` seconds into the segment (clamped)."""
        if self._profile is None or t >= self.duration:
            return self.q1.copy(), np.zeros(6)
        if t <= 0.0:
            return self.q0.copy(), np.zeros(6)
        p, v, _a = self._profile.at_time(t)
        d = self.q1 - self.q0
        return self.q0 + float(p[0]) * d, float(v[0]) * d


@dataclass(frozen=True)
class Trajectory:
    """A time-parametrised joint path: rest-to-rest segments, one after the other."""

    waypoints: NDArray[np.float64]
    segments: tuple[Segment, ...]
    limits: JointLimits

    @property
    def duration(self) -> float:
        return self.segments[-1].t0 + self.segments[-1].duration if self.segments else 0.0

    def at(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Position (6,) and velocity (6,) at time ``t`` (s) from the start; clamped to the ends."""
        if not self.segments:
            return self.waypoints[-1].copy(), np.zeros(6)
        starts = [s.t0 for s in self.segments]
        k = max(0, int(np.searchsorted(starts, t, side="right")) - 1)
        s = self.segments[k]
        return s.at(t - s.t0)

    def sample(self, rate_hz: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Times (N,), positions (N, 6) and velocities (N, 6) every ``1/rate_hz`` s, end included.

        Raises:
            RobotError: ``rate_hz`` not positive.
        """
        if not (rate_hz > 0 and math.isfinite(rate_hz)):
            raise RobotError(f"sample rate is {rate_hz!r} Hz; expected a positive number")
        n = int(math.floor(self.duration * rate_hz)) + 1
        times = np.arange(n) / rate_hz
        if times[-1] < self.duration:
            times = np.append(times, self.duration)
        Q = np.empty((len(times), 6))
        QD = np.empty((len(times), 6))
        for i, t in enumerate(times):
            Q[i], QD[i] = self.at(float(t))
        return times, Q, QD

    def movej_path(self) -> list[list[float]]:
        """The path as ur_rtde's ``moveJ(path)`` entries ``[q1..q6, v, a, blend=0]``.

        Blend 0: the controller stops at each waypoint, as this trajectory does, so it stays on
        the checked straight segments. A segment of zero length is left out.
        """
        return [
            [*map(float, s.q1), float(s.lead_speed), float(s.lead_accel), 0.0] for s in self.segments if s.duration > 0
        ]


def _segment(q0: NDArray[np.float64], q1: NDArray[np.float64], t0: float, lim: JointLimits) -> Segment:
    d = q1 - q0
    ad = np.abs(d)
    if float(ad.max()) < 1e-12:
        return Segment(q0, q1, t0, 0.0, 0.0, 0.0)
    # the path parameter s ∈ [0, 1] along the straight line q0 + s·d, limited by the tightest
    # joint: one 1-DOF profile, so every joint moves in proportion (exactly on the checked line)
    # whatever the ratios of the joints' limits (a phase-synchronised 6-DOF profile does not
    # exist when another joint's velocity/acceleration ratio differs from the leading one's)
    nz = ad > 1e-12
    s_v = float(np.min(lim.velocity[nz] / ad[nz]))
    s_a = float(np.min(lim.acceleration[nz] / ad[nz]))
    s_j = float(np.min(lim.jerk / ad[nz])) if math.isfinite(lim.jerk) else math.inf
    inp = InputParameter(1)
    inp.current_position = [0.0]
    inp.target_position = [1.0]
    inp.current_velocity = [0.0]
    inp.target_velocity = [0.0]
    inp.max_velocity = [s_v]
    inp.max_acceleration = [s_a]
    inp.max_jerk = [s_j]
    prof = _RuckigTrajectory(1)
    res = Ruckig(1).calculate(inp, prof)
    if res not in (Result.Working, Result.Finished):
        raise RobotError(f"no trajectory for segment {np.round(q0, 4).tolist()} → {np.round(q1, 4).tolist()}: {res}")
    lead = int(np.argmax(ad))
    return Segment(q0, q1, t0, float(prof.duration), s_v * ad[lead], s_a * ad[lead], prof)


def time_parametrize(
    path: ArrayLike,
    limits: JointLimits = UR10E,
    speed_fraction: float = 0.5,
    accel_fraction: float = 1.0,
) -> Trajectory:
    """Time-parametrise a piecewise-linear joint path within ``limits`` × fractions.

    Args:
        path: (K, 6) waypoints, K ≥ 1 (rad).
        limits: joint limits (default :data:`UR10E`).
        speed_fraction: fraction of the velocity limits to use, in (0, 1].
        accel_fraction: fraction of the acceleration limits to use, in (0, 1].

    Returns:
        A :class:`Trajectory` that stops at each waypoint and moves on straight joint-space lines.

    Raises:
        RobotError: a malformed path (shape, NaN) or a fraction outside (0, 1].
    """
    P = np.atleast_2d(np.asarray(path, dtype=np.float64))
    if P.ndim != 2 or P.shape[1] != 6 or len(P) < 1:
        raise RobotError(f"joint path has shape {P.shape}; expected (K, 6) with K >= 1")
    if not np.isfinite(P).all():
        raise RobotError("joint path contains NaN or infinite values")
    lim = limits.scaled(speed_fraction, accel_fraction)
    segs: list[Segment] = []
    t = 0.0
    for a, b in zip(P[:-1], P[1:], strict=True):
        s = _segment(a, b, t, lim)
        segs.append(s)
        t += s.duration
    return Trajectory(P, tuple(segs), lim)
