"""The arm (``robot``: sim or a UR10e) and the mobile base (``base``: sim or manual), with each backend's own fields."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, StrictBool

from cellctl.config.backends import register_backend
from cellctl.strict_model import ConfigModel as _Model


class UrFaultPolicy(_Model):
    """What the UR backend treats as a fault (reported, token withdrawn, motion stopped)."""

    reduced_mode: StrictBool = Field(default=True, description="reduced (safety-scaled) mode is a fault")
    data_stale_ms: float = Field(default=90.0, gt=0, le=5000, description="no fresh RTDE data this long: a fault")
    monitor_hz: float = Field(default=100.0, ge=20, le=500, description="safety/joint poll rate of the worker")
    watchdog_hz: float = Field(default=5.0, ge=1, le=500, description="controller stops the program below this")


class UrConfig(_Model):
    """``robot.backend: ur`` — a UR10e over ur-rtde (RTDE 30004, script 30003, dashboard 29999)."""

    host: str = Field(default="127.0.0.1", description="controller address (ur-rtde fixes the ports)")
    expected_model: str = Field(default="UR10e", description="checked against the dashboard's model")
    expected_serial: str | None = Field(default=None, description="checked against the dashboard's serial")
    accel_fraction: float = Field(default=1.0, gt=0, le=1, description="of the motion module's acceleration limits")
    stop_decel: float = Field(default=4.0, gt=0, le=40, description="stopJ deceleration, rad/s² (leading axis)")
    connect_attempts: int = Field(default=4, ge=1, le=20, description="connect tries, back-off doubling from 0.25 s")
    tcp_warn_m: float = Field(default=0.005, gt=0, le=0.1, description="robot TCP vs model FK: warn above")
    joint_tolerance_rad: float = Field(default=0.002, gt=0, le=0.1, description="arrival check at a goal")
    twin: StrictBool = Field(
        default=False, description="the controller is `cellctl sim ur-controller`: publish the twin's SimState"
    )
    faults: UrFaultPolicy = Field(default_factory=UrFaultPolicy)


@register_backend("robot", "sim")
class SimRobotFields(_Model):
    """``robot.backend: sim`` — the pybullet twin's arm (and the twin's time)."""

    speed_scale: float = Field(default=1.0, gt=0, le=1000, description=">1 runs motions faster")


@register_backend("robot", "ur")
class UrRobotFields(_Model):
    """``robot.backend: ur`` — a UR10e over ur-rtde."""

    ur: UrConfig = Field(default_factory=UrConfig)


class RobotConfig(SimRobotFields, UrRobotFields):
    """The arm: ``backend`` picks the worker's implementation; fields only one backend reads are its
    registered class's (:data:`BACKENDS`)."""

    backend: Literal["sim", "ur"] = Field(default="sim", description="sim: the pybullet twin; ur: a UR10e (robot.ur)")
    speed_fraction: float = Field(default=0.5, gt=0, le=1, description="of the UR10e joint speed limits (sim and ur)")
    settle_s: float = Field(default=0.2, ge=0, le=10, description="wait after a move before it is reported done")
    joint_state_hz: float = Field(default=10.0, gt=0, le=500, description="rate the robot worker publishes JointState")
    # read by both planned backends (cellctl.workers.robot._planned), not only the sim
    plan_timeout_s: float = Field(default=3.0, gt=0, le=60, description="RRTConnect budget per move")
    collision_margin_m: float = Field(default=0.005, ge=0, le=0.1, description="clearance around the arm")
    hand_eye: Path | None = Field(
        default=None,
        description="T_flange_cam JSON from `cellctl calibrate hand-eye`; None: the nominal mount (robot_model)",
    )


@register_backend("base", "sim")
class SimBaseFields(_Model):
    """``base.backend: sim`` — the twin parks the base (no fields of its own)."""


@register_backend("base", "manual")
class ManualBaseFields(_Model):
    """``base.backend: manual`` — an operator or the PLC parks the base and confirms."""

    confirm_timeout_s: float = Field(default=300.0, gt=0, le=3600, description="wait for the confirmation")


class BaseConfig(SimBaseFields, ManualBaseFields):
    """The mobile base: ``sim`` (the twin parks it) or ``manual`` (an operator/PLC parks and confirms)."""

    backend: Literal["sim", "manual"] = Field(default="sim", description="sim: the twin parks it; manual: confirmed")
    # An AMR docking on its markers repeats to a few mm; its map pose is what carries the bin pose to a
    # station that cannot see the board (bin_pose_source base_odometry), so its error bounds the cycle's there.
    localisation_error_m: float = Field(
        default=0.005, ge=0, le=0.5, description="error of the parked pose the base reports (sim: drawn per park)"
    )
    localisation_error_deg: float = Field(
        default=0.2, ge=0, le=30, description="yaw error of the parked pose the base reports (sim: drawn per park)"
    )
