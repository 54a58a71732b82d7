"""The camera (``camera``: sim, opencv or folder), with each backend's own fields."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field

from cellctl.config.backends import register_backend
from cellctl.images import MAX_IMAGE_PIXELS, MIN_IMAGE_SIDE
from cellctl.strict_model import ConfigModel as _Model


@register_backend("camera", "sim")
class SimCameraFields(_Model):
    """``camera.backend: sim`` — the twin's renderer."""

    noise_sigma: float = Field(default=2.0, ge=0, le=50, description="sensor noise, 8-bit grey levels")


@register_backend("camera", "opencv")
class OpenCvCameraFields(_Model):
    """``camera.backend: opencv`` — a device or stream through OpenCV."""

    device: str = Field(default="0", description="device index or stream URL")


@register_backend("camera", "folder")
class FolderCameraFields(_Model):
    """``camera.backend: folder`` — replays images from a folder."""

    folder: Path | None = Field(default=None, description="directory of images to replay")


class CameraConfig(SimCameraFields, OpenCvCameraFields, FolderCameraFields):
    """The camera: ``backend`` picks the worker's implementation; fields only one backend reads are its
    registered class's (:data:`BACKENDS`)."""

    backend: Literal["sim", "opencv", "folder"] = Field(
        default="sim", description="sim: the twin's renderer; opencv: a device or stream; folder: replay images"
    )
    width: int = Field(default=1280, gt=0, description="image width, px")
    height: int = Field(default=720, gt=0, description="image height, px")
    format: Literal["png", "jpeg"] = Field(default="png", description="image encoding on the wire")
    fx: float | None = Field(default=None, gt=0, description="px; None: D435 colour defaults scaled to width")
    fy: float | None = Field(default=None, gt=0, description="px; None: same as fx")
    cx: float | None = Field(default=None, description="px; None: image centre")
    cy: float | None = Field(default=None, description="px; None: image centre")
    max_image_pixels: int = Field(
        default=MAX_IMAGE_PIXELS,
        ge=MIN_IMAGE_SIDE * MIN_IMAGE_SIDE,
        description="pixel budget (width × height) of any image decoded (captures, classify, folder), checked "
        "from the PNG/JPEG header before decoding; a bigger one is refused (decompression bombs)",
    )
