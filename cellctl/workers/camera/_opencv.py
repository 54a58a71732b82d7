"""OpenCV camera backend: a device index (``"0"``) or a stream URL (``rtsp://…``)."""

from __future__ import annotations

from typing import Any

from cellctl.config import CellConfig
from cellctl.errors import CameraError
from cellctl.geometry.camera import CameraModel
from cellctl.images import encode_image
from cellctl.messages import CaptureReply
from cellctl.workers.camera._port import Camera

__all__ = ["OpenCVCamera"]


class OpenCVCamera(Camera):
    """Frames from ``cv2.VideoCapture``; intrinsics from the config (calibrate them)."""

    name = "opencv"

    def __init__(self, cfg: CellConfig) -> None:
        self.device = cfg.camera.device
        self.cam_cfg = cfg.camera
        self.intrinsics = CameraModel.from_config(cfg.camera).intrinsics()
        self._cap: Any = None

    def connect(self) -> None:
        import cv2

        src: int | str = int(self.device) if self.device.isdigit() else self.device
        cap = cv2.VideoCapture(src)
        if not cap.isOpened():
            cap.release()
            raise CameraError(f"camera device {self.device!r} cannot be opened (no such device or stream)")
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.cam_cfg.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.cam_cfg.height)
        self._cap = cap

    @property
    def is_connected(self) -> bool:
        return self._cap is not None

    def capture(self, fmt: str) -> tuple[CaptureReply, bytes]:
        self._require_connected()
        ok, frame = self._cap.read()
        if not ok or frame is None:
            raise CameraError(f"camera device {self.device!r} returned no frame")
        h, w = frame.shape[:2]
        if (w, h) != (self.intrinsics.width, self.intrinsics.height):
            raise CameraError(
                f"camera device {self.device!r} delivers {w}x{h}, but the intrinsics are for "
                f"{self.intrinsics.width}x{self.intrinsics.height}; set camera.width/height"
            )
        return CaptureReply(format=fmt, intrinsics=self.intrinsics), encode_image(frame[..., ::-1], fmt, CameraError)

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None
