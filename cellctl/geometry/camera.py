"""The cell's camera model: pinhole intrinsics, distortion and the sensor's usable ranges.

One definition for every consumer: the twin renders with it (``cellctl.sim.render``, the
sim camera worker), the planner decides visibility with it (``cellctl.planning.visibility``),
the camera workers report it on the wire (:meth:`CameraModel.intrinsics` →
:class:`cellctl.messages.Intrinsics`) and the benches measure with it.

Where the values live: the ``camera`` section of the cell config (``fx``, ``fy``, ``cx``,
``cy``, ``width``, ``height``; :meth:`CameraModel.from_config`). Unset values default to
:data:`D435_COLOR`, the RealSense D435 colour stream at 1280×720 with fx = fy = 920 px
(69.6° × 42.7° field of view), scaled to the configured resolution, so a 640×360 twin sees
the same field of view as a 1280×720 one.

Frames: the camera optical frame is +Z forward, +X right and +Y down in the image; pixel
``(u, v) = (fx·x/z + cx, fy·y/z + cy)``.

Light module: numpy and the wire/config models only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import ConfigError

if TYPE_CHECKING:
    from cellctl.config import CameraConfig
    from cellctl.messages import Intrinsics

__all__ = ["D435_COLOR", "CameraModel"]

_NO_DISTORTION = (0.0, 0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class CameraModel:
    """A pinhole camera with OpenCV distortion and the ranges at which it measures.

    Attributes:
        width, height: image size, px.
        fx, fy, cx, cy: pinhole parameters, px.
        dist: OpenCV distortion coefficients (k1, k2, p1, p2, k3, …); the twin renders an
            ideal pinhole and ignores them.
        dov: (near, far) depth-of-view range, m (paper Table 1: 0.175–0.6).
        max_glance_deg: largest angle between a view ray and a face normal at which the
            face still counts as seen, deg (paper: 60).

    Raises:
        ConfigError: (on construction) a non-positive size or focal length, a non-finite
            value, or a depth-of-view range that is not ``0 <= near < far``.
    """

    width: int = 1280
    height: int = 720
    fx: float = 920.0
    fy: float = 920.0
    cx: float = 640.0
    cy: float = 360.0
    dist: tuple[float, ...] = _NO_DISTORTION
    dov: tuple[float, float] = (0.175, 0.6)
    max_glance_deg: float = 60.0

    def __post_init__(self) -> None:
        # plan files and configs hand lists and JSON numbers: normalise, so the model stays
        # hashable and a malformed file gets a ConfigError naming the field, not a TypeError
        for name in ("fx", "fy", "cx", "cy", "max_glance_deg", "dist", "dov"):
            value = getattr(self, name)
            try:
                if name in ("dist", "dov"):
                    if isinstance(value, (str, bytes)):
                        raise TypeError(name)
                    norm: Any = tuple(float(x) for x in value)
                else:
                    if isinstance(value, bool):
                        raise TypeError(name)
                    norm = float(value)
            except (TypeError, ValueError):
                raise ConfigError(f"camera {name} {value!r} is not a number (or list of numbers)") from None
            object.__setattr__(self, name, norm)
        if isinstance(self.width, bool) or isinstance(self.height, bool):
            raise ConfigError(f"camera size {self.width!r}×{self.height!r} must be whole pixels")
        try:
            whole = int(self.width) == self.width and int(self.height) == self.height
        except (TypeError, ValueError):
            whole = False
        if not whole or self.width <= 0 or self.height <= 0:
            raise ConfigError(f"camera size {self.width}×{self.height} must be positive whole pixels")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        values = (self.fx, self.fy, self.cx, self.cy, self.max_glance_deg, *self.dist, *self.dov)
        if not all(math.isfinite(v) for v in values):
            raise ConfigError(f"camera model has non-finite values: {self!r}")
        if self.fx <= 0 or self.fy <= 0:
            raise ConfigError(f"camera focal lengths fx={self.fx}, fy={self.fy} must be positive pixels")
        if len(self.dov) != 2 or not 0 <= self.dov[0] < self.dov[1]:
            raise ConfigError(f"camera depth of view {list(self.dov)} must be [near, far] m with 0 <= near < far")
        if not 0 < self.max_glance_deg <= 90:
            raise ConfigError(f"camera max_glance_deg {self.max_glance_deg} must be in (0, 90]")

    # --- derived ---------------------------------------------------------------------------

    def K(self) -> NDArray[np.float64]:
        """The 3×3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def fov_deg(self) -> tuple[float, float]:
        """Horizontal and vertical field of view, degrees."""
        return (
            math.degrees(2 * math.atan2(self.width / 2, self.fx)),
            math.degrees(2 * math.atan2(self.height / 2, self.fy)),
        )

    def scaled(self, factor: float) -> CameraModel:
        """The same camera at ``factor`` × the resolution (same field of view; low-res renders)."""
        if not factor > 0:
            raise ConfigError(f"camera scale factor {factor!r} must be positive")
        return replace(
            self,
            width=max(1, int(round(self.width * factor))),
            height=max(1, int(round(self.height * factor))),
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=self.cx * factor,
            cy=self.cy * factor,
        )

    def at_resolution(self, width: int, height: int) -> CameraModel:
        """This camera's field of view at ``width`` × ``height`` px (focal length scaled by width)."""
        f = width / self.width
        return replace(self, width=width, height=height, fx=self.fx * f, fy=self.fy * f, cx=width / 2, cy=height / 2)

    # --- conversions -----------------------------------------------------------------------

    def intrinsics(self) -> Intrinsics:
        """The wire form (:class:`cellctl.messages.Intrinsics`) a camera reports with each capture."""
        from cellctl.messages import Intrinsics

        return Intrinsics(
            width=self.width, height=self.height, fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy, dist=list(self.dist)
        )

    @classmethod
    def from_intrinsics(cls, intr: Any, **ranges: Any) -> CameraModel:
        """From anything with ``width, height, fx, fy, cx, cy`` (and optionally ``dist``), e.g.
        a capture's :class:`~cellctl.messages.Intrinsics`; ``ranges`` sets ``dov``/``max_glance_deg``."""
        dist: Sequence[float] = getattr(intr, "dist", _NO_DISTORTION)
        return cls(
            width=int(intr.width),
            height=int(intr.height),
            fx=float(intr.fx),
            fy=float(intr.fy),
            cx=float(intr.cx),
            cy=float(intr.cy),
            dist=tuple(dist),
            **ranges,
        )

    @classmethod
    def from_config(cls, cam: CameraConfig, base: CameraModel | None = None) -> CameraModel:
        """The configured camera: the ``camera`` section's values, unset ones from ``base``
        (default :data:`D435_COLOR`) at the configured resolution."""
        ref = (base or D435_COLOR).at_resolution(cam.width, cam.height)
        fx = cam.fx if cam.fx is not None else ref.fx
        return replace(
            ref,
            fx=fx,
            fy=cam.fy if cam.fy is not None else fx,
            cx=cam.cx if cam.cx is not None else ref.cx,
            cy=cam.cy if cam.cy is not None else ref.cy,
        )

    def to_json(self) -> dict[str, Any]:
        """Plain JSON types (lists, not tuples), as plan files record it."""
        return {
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "dist": list(self.dist),
            "dov": list(self.dov),
            "max_glance_deg": self.max_glance_deg,
        }


D435_COLOR = CameraModel()
"""RealSense D435 colour stream at 1280×720: fx = fy = 920 px, principal point at the centre."""
