"""The planner: the plan cache, the pose tolerance, whole-bin plans and their cycle-time model."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, StrictBool

from cellctl.strict_model import ConfigModel as _Model
from cellctl.surface import Surface, per_surface


class PoseTolerance(_Model):
    """How far the measured bin pose (robot base frame) may be from a plan's and still be adjusted.

    Two parks differ by up to twice the base's parking error (plus the lever of its yaw error),
    so the tolerance must exceed that, or every cycle replans.
    """

    translation_mm: float = Field(default=80.0, gt=0, description="bin position difference, mm")
    rotation_deg: float = Field(default=4.0, gt=0, description="bin orientation difference, deg")


class WholeBinConfig(_Model):
    """Whole-bin plans (cellctl.planning.stations / whole): stations around the bin, cycle-time model."""

    enabled: StrictBool = Field(
        default=True,
        description="the cycle visits every station of the newest whole-bin plan and scans both surfaces; "
        "false: one station, one surface (planner.surface), which classifier.verdict.min_seen_fraction calls "
        "`incomplete` rather than `clean`",
    )
    candidates: int = Field(default=8, ge=1, le=36, description="station candidates around the bin")
    max_stations: int = Field(default=4, ge=1, le=36, description="stations a whole-bin plan may use")
    park_distance_m: float = Field(default=0.75, gt=0, le=3, description="base origin beyond the bin's extent")
    min_station_gain_pct: float = Field(
        default=2.0, ge=0, lt=100, description="% of a surface's bound a station must add"
    )
    view_min_gain_pct: float = Field(
        default=0.15, ge=0, lt=100, description="% of a surface's bound a viewpoint must add"
    )
    allowed_deg: list[float] | None = Field(
        default=None, description="approach directions the base may use (deg, bin frame; -90 = board side); None: all"
    )
    cabin_half_m: tuple[float, float] = Field(default=(2.5, 2.5), description="cabin half-extents x, y (m)")
    bin_in_cabin: tuple[float, float, float] = Field(
        default=(0.0, 0.0, 0.0), description="bin footprint x, y (m) and yaw (deg) in the cabin"
    )
    settle_s: float = Field(default=0.5, ge=0, le=10, description="modelled settle per viewpoint (paper: 1 s)")
    capture_s: float = Field(default=0.1, ge=0, le=10, description="modelled capture per viewpoint")
    base_speed_m_s: float = Field(default=0.5, gt=0, le=3, description="modelled base travel speed")
    base_turn_deg_s: float = Field(default=45.0, gt=0, le=360, description="modelled base turn rate")
    park_s: float = Field(default=3.0, ge=0, le=60, description="docking time per station")
    inner_candidates: int = Field(
        default=4, ge=0, le=36, description="directions of the inner station ring (0: outer ring only)"
    )
    inner_park_distance_m: float = Field(
        default=0.35, gt=0, le=3, description="inner ring: base origin beyond the bin's extent (reach into deep bins)"
    )
    odometry_error_m: float = Field(
        default=0.01,
        ge=0,
        le=0.2,
        description="a station without the board: extra clearance of its configurations from the bin, for the "
        "error of the pose the base's odometry carries there (two base.localisation_error reports); 0: none",
    )
    chains: Literal["all", "needed"] = Field(
        default="needed",
        description="a viewpoint joined to home through others: visit its chain's viewpoints only where its tour "
        "needs them (the selection makes up what they saw) or always (all)",
    )
    min_bound_pct: dict[Surface, Annotated[float, Field(ge=0, le=100)]] = Field(
        default_factory=lambda: per_surface(91.0, 86.0),
        description="per surface, % of its upper bound the selection must see: below it viewpoints are added past "
        "view_min_gain_pct (0 / absent: no floor)",
    )
    cycle_budget_s: float = Field(
        default=180.0,
        ge=0,
        le=3600,
        description="takt for one bin's modelled cycle (s): a plan above it takes one station fewer where the floors "
        "(min_bound_pct) still hold, then drops the viewpoints that see least per second down to the floors; 0: none",
    )


class PlannerConfig(_Model):
    plans_dir: Path = Field(default=Path("models/plans"), description="folder of the plan cache")
    tolerance: PoseTolerance = Field(default_factory=PoseTolerance)
    surface: Surface = Field(default="external", description="the surface a single-station cycle scans")
    seed_pct: float = Field(default=10.0, gt=0, le=100, description="% of the surface's faces used as viewpoint seeds")
    mode: Literal["fast", "paper"] = Field(
        default="fast", description="fast: the project's planner; paper: the paper's RRT* baseline"
    )
    seed: int = Field(default=0, description="random seed of the planner (same seed, same plan)")
    whole: WholeBinConfig = Field(default_factory=WholeBinConfig)
