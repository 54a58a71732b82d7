"""Time-parametrised joint motion: a collision-checked joint path → a trajectory within the
UR10e joint velocity **and** acceleration limits, shared by the sim arm and the real UR driver."""

from cellctl.motion._trajectory import (
    UR10E,
    UR10E_JOINT_ACCEL,
    UR10E_JOINT_ACCEL_CEILING,
    JointLimits,
    Segment,
    Trajectory,
    arm_fractions,
    time_parametrize,
)

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
