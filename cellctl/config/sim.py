"""The twin (used by sim backends only): its scenario and the emulated UR10e controller."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, StrictBool

from cellctl.strict_model import ConfigModel as _Model


class UrControllerConfig(_Model):
    """``cellctl sim ur-controller``: the emulated UR10e controller (a twin component)."""

    host: str = Field(default="127.0.0.1", description="loopback address it listens on (127.0.0.0/8)")
    control_port: int = Field(default=30099, ge=1024, le=65535, description="fault-injection text socket")
    model: str = Field(default="UR10", description="model name the dashboard reports")
    serial: str = Field(default="20235500001", description="serial number the dashboard reports")
    polyscope: str = Field(default="5.11.1.108318", description="PolyScope version it reports (e-Series: 5.x)")
    robot_mode: Literal["RUNNING", "IDLE", "POWER_OFF"] = Field(default="RUNNING", description="robot mode at start")
    remote_control: StrictBool = Field(default=True, description="the pendant is in remote control (RTDE may drive it)")
    unlock_delay_s: float = Field(default=5.0, ge=0, le=60, description="protective stop: unlock after (s)")
    stop_decel: float = Field(default=10.0, gt=0, le=40, description="safety stops' deceleration, rad/s²")


class SimConfig(_Model):
    """The pybullet twin's scenario (used by sim backends only)."""

    bin_type: str = Field(default="case_study", description="catalog bin the twin shows")
    bin_pose_xyz_yaw: tuple[float, float, float, float] = Field(
        default=(0.0, 0.0, 0.0, 0.0), description="bin pose in the world: x, y, z (m), yaw (deg)"
    )
    dirty: StrictBool = Field(default=False, description="the twin's bin carries powder")
    powder_amount: float = Field(default=0.5, ge=0, le=1, description="how much powder a dirty bin carries (0..1)")
    seed: int = Field(default=0, description="random seed of the scenario (powder, parking errors)")
    approach_error_m: float = Field(default=0.02, ge=0, le=0.5, description="parking position error, radius (m)")
    approach_error_deg: float = Field(default=1.0, ge=0, le=30, description="parking yaw error, ± deg")
    ur_controller: UrControllerConfig = Field(default_factory=UrControllerConfig)
