"""The camera worker's capture: the request, the reply's metadata, the intrinsics."""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, FiniteFloat

from cellctl.messages.base import PoseMsg, WireMessage, now_iso


class Intrinsics(BaseModel):
    """Pinhole intrinsics in pixels, OpenCV distortion coefficients."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    width: int = Field(gt=0, le=65535)
    height: int = Field(gt=0, le=65535)
    fx: FiniteFloat = Field(gt=0)
    fy: FiniteFloat = Field(gt=0)
    cx: FiniteFloat
    cy: FiniteFloat
    dist: list[FiniteFloat] = Field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0, 0.0], max_length=14)

    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


class CaptureRequest(WireMessage):
    type: Literal["cellctl/CaptureRequest"] = "cellctl/CaptureRequest"
    v: Literal[1] = 1
    format: Literal["png", "jpeg"] = "png"


class CaptureReply(WireMessage):
    """Metadata of a captured image; the encoded image is the reply payload."""

    type: Literal["cellctl/CaptureReply"] = "cellctl/CaptureReply"
    v: Literal[1] = 1
    format: Literal["png", "jpeg"]
    intrinsics: Intrinsics
    camera_pose: PoseMsg | None = None
    stamp: str = Field(default_factory=now_iso)
