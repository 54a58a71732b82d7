"""Washing: the nozzle (a second tool beside the camera) and the wash-and-verify rounds."""

from __future__ import annotations

from pydantic import Field

from cellctl.strict_model import ConfigModel as _Model


class NozzleConfig(_Model):
    """The washing nozzle (:class:`cellctl.washing.nozzle.NozzleModel`), a second tool beside the camera."""

    half_angle_deg: float = Field(default=12.0, gt=0, lt=60, description="spray cone half-angle")
    working_distance_m: tuple[float, float] = Field(default=(0.15, 0.5), description="near, far stand-off (m)")
    max_incidence_deg: float = Field(default=60.0, gt=0, lt=90, description="jet vs face normal, at most")
    footprint_m: float = Field(default=0.05, gt=0, le=1, description="diameter of the spot one pass cleans")
    removal_per_pass: float = Field(default=0.8, gt=0, le=1, description="fraction of the powder one pass removes")
    clean_residual: float = Field(default=0.05, gt=0, lt=1, description="powder fraction that may stay")
    overlap: float = Field(default=0.3, ge=0, lt=0.9, description="raster line overlap, fraction of the footprint")
    mount_xyz_rpy: tuple[float, float, float, float, float, float] = Field(
        default=(0.0, 0.0, 0.25, 0.0, 0.0, 0.0), description="nozzle tip in the flange frame: m, m, m, deg, deg, deg"
    )
    lance_radius_m: float = Field(default=0.015, gt=0, lt=0.1, description="lance radius (m): its body clearance")
    # Whether the fields make a nozzle that works (its footprint, reach, clearance) is the nozzle model's check
    # (cellctl.washing.nozzle.NozzleModel), run by the composition root (cellctl.app.preflight) and its factory.


class WashConfig(_Model):
    """Wash-and-verify (cellctl.washing): which faces to wash and how many rounds."""

    threshold: float = Field(default=0.5, gt=0, lt=1, description="face dirt probability that is washed")
    margin_m: float = Field(default=0.02, ge=0, le=0.3, description="targets dilated by this much around dirt")
    max_rounds: int = Field(default=3, ge=1, le=20, description="wash → re-inspect rounds before 'dirty'")
    splash_m: float = Field(
        default=0.05, ge=0, le=0.5, description="re-inspect the washed faces' neighbours this far (the jet splashes)"
    )
    # a clean verdict covers only what the cell saw; below this share of the bin's area (both
    # surfaces) no dirt seen is not a clean bin: `dirty`, reason "unverified" (docs/washing/README.md)
    min_seen_fraction: float = Field(
        default=0.6,
        ge=0,
        le=1,
        description="`clean` needs the scan and re-inspections to have seen this share of the bin's area",
    )
