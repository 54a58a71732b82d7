"""The robot worker's ops: approach, move, state, maintenance, stop (``robot/wash``: :mod:`.washing`)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, FiniteFloat, model_validator

from cellctl.messages.base import Joints, PoseMsg, WireMessage, now_iso


class JointState(WireMessage):
    type: Literal["cellctl/JointState"] = "cellctl/JointState"
    v: Literal[1] = 1
    names: list[str]
    position: list[float]
    stamp: str = Field(default_factory=now_iso)


class ApproachRequest(WireMessage):
    """Park the base beside the bin and move the arm to an observation pose."""

    type: Literal["cellctl/ApproachRequest"] = "cellctl/ApproachRequest"
    v: Literal[1] = 1
    observation_index: int = Field(default=0, ge=0, description="which observation pose (retries use the next)")
    park: bool = Field(default=True, description="False: only move the arm to the observation pose")
    base_pose: PoseMsg | None = Field(
        default=None,
        description="whole-bin station: where the base parks, in the bin frame (T_bin_base); None: the nominal park",
    )
    observe: bool = Field(
        default=True, description="False: park only, the arm stays tucked (a station that cannot see the board)"
    )


class ApproachReply(WireMessage):
    type: Literal["cellctl/ApproachReply"] = "cellctl/ApproachReply"
    v: Literal[1] = 1
    joints: Joints
    flange_pose: PoseMsg
    camera_pose: PoseMsg
    observation_index: int = 0
    base_pose: PoseMsg | None = Field(
        default=None,
        description="where the mobile base says it is parked: its localisation, frame_id 'map' (T_map_base); "
        "None: the base reports no pose",
    )


class MoveRequest(WireMessage):
    """Move to joint positions or to a camera pose (in the robot base frame)."""

    type: Literal["cellctl/MoveRequest"] = "cellctl/MoveRequest"
    v: Literal[1] = 1
    joints: Joints | None = None
    camera_pose: PoseMsg | None = None
    settle_s: float | None = Field(default=None, ge=0.0, le=60.0)

    @model_validator(mode="after")
    def _one_target(self) -> MoveRequest:
        if (self.joints is None) == (self.camera_pose is None):
            raise ValueError("give exactly one of 'joints' or 'camera_pose'")
        return self


class MoveReply(WireMessage):
    type: Literal["cellctl/MoveReply"] = "cellctl/MoveReply"
    v: Literal[1] = 1
    joints: Joints
    camera_pose: PoseMsg
    path_length_rad: FiniteFloat = 0.0
    duration_s: FiniteFloat = 0.0


class RobotStateRequest(WireMessage):
    type: Literal["cellctl/RobotStateRequest"] = "cellctl/RobotStateRequest"
    v: Literal[1] = 1


class RobotState(WireMessage):
    type: Literal["cellctl/RobotState"] = "cellctl/RobotState"
    v: Literal[1] = 1
    joints: Joints
    flange_pose: PoseMsg
    camera_pose: PoseMsg
    moving: bool = False
    speed_slider: float | None = Field(default=None, description="ur: the pendant's speed slider (0–1)")
    fault: str | None = Field(default=None, description="ur: the latched safety fault, until cleared")
    stamp: str = Field(default_factory=now_iso)


class RobotMaintenanceRequest(WireMessage):
    """An operator's explicit maintenance action on the real arm (op ``robot/maintenance``).

    Never sent by the supervisor: unlocking a protective stop needs a person who inspected its cause.
    """

    type: Literal["cellctl/RobotMaintenanceRequest"] = "cellctl/RobotMaintenanceRequest"
    v: Literal[1] = 1
    action: Literal["unlock_protective_stop", "close_safety_popup", "power_on", "brake_release", "clear_fault"]
    user: str = Field(min_length=1, description="who asked (logged)")


class RobotMaintenanceReply(WireMessage):
    type: Literal["cellctl/RobotMaintenanceReply"] = "cellctl/RobotMaintenanceReply"
    v: Literal[1] = 1
    action: str
    detail: str = Field(description="the controller's answer")
    fault: str | None = None


class StopRequest(WireMessage):
    """Stop any motion now (sent on Stop/Abort/Hold)."""

    type: Literal["cellctl/StopRequest"] = "cellctl/StopRequest"
    v: Literal[1] = 1
    reason: str = ""
