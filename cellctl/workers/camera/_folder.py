"""Folder camera backend: replays the images of a directory in name order, then loops."""

from __future__ import annotations

import itertools
from pathlib import Path

from cellctl.config import CellConfig
from cellctl.errors import CameraError
from cellctl.geometry.camera import CameraModel
from cellctl.images import decode_image, encode_image
from cellctl.messages import CaptureReply
from cellctl.workers.camera._port import Camera

__all__ = ["FolderCamera"]

EXTENSIONS = {".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg"}


class FolderCamera(Camera):
    """Images from ``camera.folder`` (PNG/JPEG); re-encoded only when the format differs."""

    name = "folder"

    def __init__(self, cfg: CellConfig) -> None:
        self.folder = cfg.path(cfg.camera.folder) if cfg.camera.folder is not None else None
        self.intrinsics = CameraModel.from_config(cfg.camera).intrinsics()
        self.max_pixels = cfg.camera.max_image_pixels
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
        self._require_connected()
        path = self._files[next(self._next) % len(self._files)]
        data = path.read_bytes()
        # refuse a broken or oversized file even when passed on as is
        rgb = decode_image(data, repr(str(path)), error=CameraError, max_pixels=self.max_pixels)
        if EXTENSIONS[path.suffix.lower()] != fmt:
            data = encode_image(rgb, fmt, CameraError)
        return CaptureReply(format=fmt, intrinsics=self.intrinsics), data
