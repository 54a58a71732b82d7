"""The camera role's interface and the helpers every backend shares."""

from __future__ import annotations

import abc

import numpy as np
from numpy.typing import NDArray

from cellctl.config import CameraConfig
from cellctl.errors import CameraError
from cellctl.messages import CaptureReply, Intrinsics

__all__ = ["Camera", "encode_image", "intrinsics_from_config"]

D435_FX_AT_1280 = 920.0
"""RealSense D435 colour focal length (px) at 1280×720 (69° horizontal field of view)."""


def intrinsics_from_config(cam: CameraConfig) -> Intrinsics:
    """Intrinsics from the camera section; unset values default to the D435 colour stream."""
    fx = cam.fx if cam.fx is not None else D435_FX_AT_1280 * cam.width / 1280.0
    fy = cam.fy if cam.fy is not None else fx
    cx = cam.cx if cam.cx is not None else cam.width / 2.0
    cy = cam.cy if cam.cy is not None else cam.height / 2.0
    return Intrinsics(width=cam.width, height=cam.height, fx=fx, fy=fy, cx=cx, cy=cy)


def encode_image(rgb: NDArray[np.uint8], fmt: str) -> bytes:
    """Encode an RGB (H, W, 3) uint8 image as PNG or JPEG bytes.

    Raises:
        CameraError: unknown format or the encoder failed.
    """
    import cv2

    ext = {"png": ".png", "jpeg": ".jpg"}.get(fmt)
    if ext is None:
        raise CameraError(f"image format {fmt!r} is unknown; expected 'png' or 'jpeg'")
    ok, buf = cv2.imencode(ext, np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise CameraError(f"cannot encode a {rgb.shape} image as {fmt}")
    return buf.tobytes()


class Camera(abc.ABC):
    """An RGB camera. ``capture`` blocks until a frame is encoded.

    Raises (every method):
        CameraError: not connected, no frame, bad format — the message says which.
    """

    name: str = "camera"

    @abc.abstractmethod
    def connect(self) -> None:
        """Open the device/source; CameraError when it cannot be opened."""

    @property
    @abc.abstractmethod
    def is_connected(self) -> bool: ...

    @abc.abstractmethod
    def capture(self, fmt: str) -> tuple[CaptureReply, bytes]:
        """One frame: its metadata (intrinsics, camera pose if known) and the encoded bytes."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release the device."""

    def _require_connected(self) -> None:
        if not self.is_connected:
            raise CameraError(f"camera {self.name!r} is not connected")

    def __enter__(self) -> Camera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
