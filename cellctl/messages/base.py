"""The base of every wire message: the versioned envelope, poses, joints, the stamp, a worker's error reply."""

from __future__ import annotations

import datetime as _dt
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, field_validator

WIRE_VERSION = 1

ROBOT_JOINTS = 6
"""Joint count of the arm (UR10e); joint vectors on the wire have exactly this many entries."""

Joints = Annotated[list[FiniteFloat], Field(min_length=ROBOT_JOINTS, max_length=ROBOT_JOINTS)]
"""Joint positions in radians; NaN/inf or a wrong length is refused when the message is decoded."""


def now_iso() -> str:
    """UTC time as ISO-8601 with milliseconds, the stamp format of every message."""
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


class WireMessage(BaseModel):
    """Base of every wire message: frozen, strict about unknown fields."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    type: str
    v: int


class PoseMsg(BaseModel):
    """A pose: position in metres, orientation as a unit quaternion ``xyzw``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    position: tuple[FiniteFloat, FiniteFloat, FiniteFloat]
    orientation: tuple[FiniteFloat, FiniteFloat, FiniteFloat, FiniteFloat] = (0.0, 0.0, 0.0, 1.0)
    frame_id: str = Field(default="base", max_length=64)

    @field_validator("orientation")
    @classmethod
    def _rotation(cls, q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        # Readers normalise the quaternion; one of (near) zero length has no direction to normalise to.
        if sum(x * x for x in q) < 1e-12:
            raise ValueError(f"orientation {q} is not a rotation: expected a unit quaternion xyzw")
        return q

    @classmethod
    def from_matrix(cls, T: Any, frame_id: str = "base") -> PoseMsg:
        from cellctl.geometry.transforms import pose_from_transform

        p, q = pose_from_transform(np.asarray(T))
        return cls(position=p, orientation=q, frame_id=frame_id)

    def matrix(self) -> np.ndarray:
        from cellctl.geometry.transforms import transform_from_pose

        return transform_from_pose((self.position, self.orientation))


class ErrorReply(WireMessage):
    """What a worker sends with ``reply_err``: a kind and a human-readable reason."""

    type: Literal["cellctl/ErrorReply"] = "cellctl/ErrorReply"
    v: Literal[1] = 1
    kind: str = Field(description="exception class name, e.g. RobotError, ProtocolError")
    reason: str
