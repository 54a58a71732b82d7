"""Folder camera backend: replays the images of a directory in name order, then loops."""

from __future__ import annotations

import itertools
from pathlib import Path

from cellctl.config import CellConfig
from cellctl.errors import CameraError
from cellctl.messages import CaptureReply
from cellctl.workers.camera._port import Camera, encode_image, intrinsics_from_config

__all__ = ["FolderCamera"]

EXTENSIONS = {".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg"}


class FolderCamera(Camera):
    """Images from ``camera.folder`` (PNG/JPEG); re-encoded only when the format differs."""

    name = "folder"

    def __init__(self, cfg: CellConfig) -> None:
        self.folder = cfg.path(cfg.camera.folder) if cfg.camera.folder is not None else None
        self.intrinsics = intrinsics_from_config(cfg.camera)
        self._files: list[Path] = []
        self._next = itertools.count()

    def connect(self) -> None:
        if self.folder is None:
            raise CameraError("camera.folder is not set; the folder backend needs a directory of images")
        if not self.folder.is_dir():
            raise CameraError(f"camera folder {str(self.folder)!r} does not exist")
        files = sorted(p for p in self.folder.iterdir() if p.suffix.lower() in EXTENSIONS)
        if not files:
            raise CameraError(f"camera folder {str(self.folder)!r} holds no .png/.jpg images")
        self._files = files

    @property
    def is_connected(self) -> bool:
        return bool(self._files)

    def capture(self, fmt: str) -> tuple[CaptureReply, bytes]:
        import cv2
        import numpy as np

        self._require_connected()
        path = self._files[next(self._next) % len(self._files)]
        data = path.read_bytes()
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise CameraError(f"image {str(path)!r} cannot be decoded")
        if EXTENSIONS[path.suffix.lower()] != fmt:
            data = encode_image(img[..., ::-1], fmt)
        return CaptureReply(format=fmt, intrinsics=self.intrinsics), data
