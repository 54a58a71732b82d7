"""The washing nozzle: spray cone, working distances, incidence limit, footprint, removal, mounting.

The paper's planner "can easily be adapted to generate the washing trajectories … by replacing
the inspection camera mounted on the robot end-effector with a washing nozzle and changing the
camera pin-hole model with the model defining the nozzle frustum of action". This is that
model. The planner's stages take a :class:`~cellctl.geometry.camera.CameraModel` and a
:class:`~cellctl.planning.robot.RobotModel`; :meth:`NozzleModel.frustum_camera` gives the
square pyramid that circumscribes the spray cone (so the visibility stage keeps a superset) and
:meth:`NozzleModel.robot_with_nozzle` a robot model whose "camera" frame is the nozzle frame,
so IK, the camera-body filter and the collision checks place the nozzle, not the camera.
:meth:`NozzleModel.sprayed` then cuts the pyramid back to the cone and the footprint.

Mounting: a **second tool** on the flange, not a tool change. The nozzle is a lance on
the flange axis (``mount_xyz_rpy``, default 25 cm out of the tool plate, long enough to reach into
the bin from its opening, jet along the
flange's +Z, parallel to the camera's optical axis); the camera stays mounted. So
inspect → wash → re-inspect needs no tool change, and the camera body is collision-checked
while washing as while scanning. The lance itself is checked by :meth:`lance_free`.

Nozzle frame: jet along +Z; origin at the nozzle tip. Metres, degrees where named ``_deg``.
Light module: numpy and the config model only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import ConfigError

if TYPE_CHECKING:
    from cellctl.config import NozzleConfig
    from cellctl.geometry.camera import CameraModel
    from cellctl.planning.robot import RobotModel

__all__ = ["DEFAULT_NOZZLE", "NozzleModel"]

ARM_REACH_M = 1.3
"""UR10e reach (:data:`cellctl.geometry.robot_model.REACH_M`, repeated here to keep this module light)."""


@dataclass(frozen=True)
class NozzleModel:
    """A round-jet washing nozzle: a spray cone with the ranges at which it cleans.

    Attributes:
        half_angle_deg: half-angle of the spray cone.
        working_distance_m: (near, far) nozzle-to-surface distance along the jet where it cleans.
        max_incidence_deg: largest angle between the jet and the face normal that still cleans.
        footprint_m: diameter of the spot one pass cleans (the jet's core); the cone's
            own spot ``2·d·tan(half_angle)`` bounds it at distance d.
        removal_per_pass: fraction of the powder under the footprint one pass removes, (0, 1].
        clean_residual: the fraction of the powder that may stay; sets the passes a face needs.
        overlap: overlap of neighbouring raster lines, fraction of the footprint.
        mount_xyz_rpy: nozzle frame in the flange frame: x, y, z (m), roll, pitch, yaw (deg).
        lance_radius_m: radius of the lance (flange → nozzle tip) for collision checks.
    """

    half_angle_deg: float = 12.0
    working_distance_m: tuple[float, float] = (0.15, 0.5)
    max_incidence_deg: float = 60.0
    footprint_m: float = 0.05
    removal_per_pass: float = 0.8
    clean_residual: float = 0.05
    overlap: float = 0.3
    mount_xyz_rpy: tuple[float, float, float, float, float, float] = (0.0, 0.0, 0.25, 0.0, 0.0, 0.0)
    lance_radius_m: float = 0.015

    def __post_init__(self) -> None:
        try:
            wd = tuple(float(x) for x in self.working_distance_m)
            mount = tuple(float(x) for x in self.mount_xyz_rpy)
        except (TypeError, ValueError):
            raise ConfigError(
                f"nozzle working_distance_m {self.working_distance_m!r} / mount_xyz_rpy {self.mount_xyz_rpy!r}"
                " must be lists of numbers"
            ) from None
        object.__setattr__(self, "working_distance_m", wd)
        object.__setattr__(self, "mount_xyz_rpy", mount)
        scalars = (
            "half_angle_deg",
            "max_incidence_deg",
            "footprint_m",
            "removal_per_pass",
            "clean_residual",
            "overlap",
            "lance_radius_m",
        )
        for name in scalars:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"nozzle {name} {v!r} must be a finite number")
            object.__setattr__(self, name, float(v))
        if len(wd) != 2 or not all(math.isfinite(x) for x in wd) or not 0 < wd[0] < wd[1]:
            raise ConfigError(f"nozzle working_distance_m {list(wd)} must be [near, far] m with 0 < near < far")
        if len(mount) != 6 or not all(math.isfinite(x) for x in mount):
            raise ConfigError(f"nozzle mount_xyz_rpy {list(mount)} must be 6 finite numbers (m, m, m, deg, deg, deg)")
        if not 0 < self.half_angle_deg < 60:
            raise ConfigError(f"nozzle half_angle_deg {self.half_angle_deg} must be in (0, 60)")
        if not 0 < self.max_incidence_deg < 90:
            raise ConfigError(f"nozzle max_incidence_deg {self.max_incidence_deg} must be in (0, 90)")
        if not 0 < self.removal_per_pass <= 1:
            raise ConfigError(f"nozzle removal_per_pass {self.removal_per_pass} must be in (0, 1]")
        if not 0 < self.clean_residual < 1:
            raise ConfigError(f"nozzle clean_residual {self.clean_residual} must be in (0, 1)")
        if not 0 <= self.overlap < 0.9:
            raise ConfigError(f"nozzle overlap {self.overlap} must be in [0, 0.9)")
        if not 0 < self.lance_radius_m < 0.1:
            raise ConfigError(f"nozzle lance_radius_m {self.lance_radius_m} must be in (0, 0.1) m")
        if not self.footprint_m > 0:
            raise ConfigError(f"nozzle footprint_m {self.footprint_m} must be positive")
        # the checks a bad nozzle fails in the field: it cannot make its own footprint, its body
        # would touch the surface at its nearest working distance, or the arm cannot hold it at
        # its farthest one
        widest = 2 * wd[1] * math.tan(math.radians(self.half_angle_deg))
        if self.footprint_m > widest:
            raise ConfigError(
                f"nozzle footprint_m {self.footprint_m} m is wider than its cone ever sprays "
                f"({widest:.3f} m at the far working distance {wd[1]} m with half_angle_deg {self.half_angle_deg})"
            )
        if wd[0] <= self.lance_radius_m:
            raise ConfigError(
                f"nozzle working_distance_m near {wd[0]} m cannot be reached: the lance (radius "
                f"{self.lance_radius_m} m) would touch the surface first"
            )
        offset = float(np.linalg.norm(mount[:3]))
        if wd[1] + offset >= ARM_REACH_M:
            raise ConfigError(
                f"nozzle working_distance_m far {wd[1]} m cannot be reached: with the mount offset {offset:.3f} m "
                f"it is beyond the arm's reach {ARM_REACH_M} m"
            )

    # --- derived ---------------------------------------------------------------------------

    @property
    def distances(self) -> tuple[float, ...]:
        """Stand-offs the planner tries, in preference order: where the cone first spans the
        footprint (nearest: the least overspray), then a third and two thirds of the way to far."""
        near, far = self.working_distance_m
        d0 = min(max(near, self.footprint_m / 2 / math.tan(math.radians(self.half_angle_deg))), far)
        return tuple(dict.fromkeys(round(d0 + f * (far - d0), 4) for f in (0.0, 1 / 3, 2 / 3)))

    @property
    def line_spacing_m(self) -> float:
        """Distance between neighbouring raster lines."""
        return self.footprint_m * (1.0 - self.overlap)

    @property
    def required_passes(self) -> int:
        """Passes one face needs so at most ``clean_residual`` of its powder stays."""
        if self.removal_per_pass >= 1.0:
            return 1
        return max(1, math.ceil(math.log(self.clean_residual) / math.log(1.0 - self.removal_per_pass) - 1e-9))

    def spot_radius(self, d: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Radius (m) of the cleaned spot at distance(s) ``d``: the footprint, bounded by the cone."""
        return np.minimum(self.footprint_m / 2, np.asarray(d, np.float64) * math.tan(math.radians(self.half_angle_deg)))

    def T_flange_nozzle(self) -> NDArray[np.float64]:
        from cellctl.geometry.transforms import transform_from_xyz_rpy

        x, y, z, r, p, yw = self.mount_xyz_rpy
        return transform_from_xyz_rpy([x, y, z], np.radians([r, p, yw]))

    def frustum_camera(self) -> CameraModel:
        """The pinhole "camera" whose square image circumscribes the spray cone, with the working
        distances as its depth of view and the incidence limit as its glance limit."""
        from cellctl.geometry.camera import CameraModel

        w = 200
        f = (w / 2) / math.tan(math.radians(self.half_angle_deg))
        return CameraModel(
            width=w,
            height=w,
            fx=f,
            fy=f,
            cx=w / 2,
            cy=w / 2,
            dov=self.working_distance_m,
            max_glance_deg=self.max_incidence_deg,
        )

    def robot_with_nozzle(self, robot: RobotModel) -> RobotModel:
        """``robot`` with its tool frame moved to the nozzle (IK then places the nozzle tip)."""
        return replace(robot, T_flange_cam=self.T_flange_nozzle())

    def sprayed(
        self, T_bin_noz: NDArray[np.float64], points: NDArray[np.float64], normals: NDArray[np.float64]
    ) -> NDArray[np.bool_]:
        """(P,) True where a surface point lies in the footprint of the jet at ``T_bin_noz`` (4, 4):
        within the working distances along the jet, within the spot radius of its axis, the jet
        meeting the surface at no more than the incidence limit. Occlusion is the caller's."""
        a = T_bin_noz[:3, 2]
        v = np.asarray(points, np.float64) - T_bin_noz[:3, 3]
        along = v @ a
        radial = np.linalg.norm(v - along[:, None] * a[None], axis=1)
        near, far = self.working_distance_m
        ok = (along >= near * 0.999) & (along <= far * 1.001)
        ok &= radial <= self.spot_radius(np.maximum(along, 0.0))
        ok &= -(np.asarray(normals) @ a) >= math.cos(math.radians(self.max_incidence_deg))
        return ok

    def lance_segment(self, T_bin_noz: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(N, 3), (N, 3): the lance from the flange to the nozzle tip for nozzle poses (N, 4, 4)."""
        from cellctl.geometry.transforms import invert

        T = np.asarray(T_bin_noz, np.float64).reshape(-1, 4, 4)
        T_bin_flange = T @ invert(self.T_flange_nozzle())
        return T_bin_flange[:, :3, 3], T[:, :3, 3]

    def to_json(self) -> dict[str, Any]:
        return {
            "half_angle_deg": self.half_angle_deg,
            "working_distance_m": list(self.working_distance_m),
            "max_incidence_deg": self.max_incidence_deg,
            "footprint_m": self.footprint_m,
            "removal_per_pass": self.removal_per_pass,
            "clean_residual": self.clean_residual,
            "overlap": self.overlap,
            "required_passes": self.required_passes,
            "mount_xyz_rpy": list(self.mount_xyz_rpy),
            "lance_radius_m": self.lance_radius_m,
        }

    @classmethod
    def from_config(cls, cfg: NozzleConfig) -> NozzleModel:
        return cls(
            half_angle_deg=cfg.half_angle_deg,
            working_distance_m=tuple(cfg.working_distance_m),
            max_incidence_deg=cfg.max_incidence_deg,
            footprint_m=cfg.footprint_m,
            removal_per_pass=cfg.removal_per_pass,
            clean_residual=cfg.clean_residual,
            overlap=cfg.overlap,
            mount_xyz_rpy=tuple(cfg.mount_xyz_rpy),
            lance_radius_m=cfg.lance_radius_m,
        )


DEFAULT_NOZZLE = NozzleModel()
"""12° round jet on a 25 cm lance, 15–50 cm stand-off, 5 cm footprint, ≤ 60° incidence, 80 % removal per pass
(2 passes to ≤ 5 %)."""
