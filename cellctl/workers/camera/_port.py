"""The camera role's interface.

Backends share the camera model (:meth:`cellctl.geometry.camera.CameraModel.from_config`)
and the image encoder (:func:`cellctl.images.encode_image`); this module holds only the ABC.
"""

from __future__ import annotations

import abc

from cellctl.errors import CameraError
from cellctl.messages import CaptureReply

__all__ = ["Camera"]


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
