"""A finished cycle's result: per viewpoint, per station, the commissioning, the wash, the verdict."""

from __future__ import annotations

import enum
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from cellctl.messages.base import PoseMsg, WireMessage, now_iso
from cellctl.messages.classifier import ReferenceReason
from cellctl.messages.command import MAX_USER_CHARS
from cellctl.messages.washing import WashResult
from cellctl.seen import Verdict
from cellctl.surface import Surface


class CycleOutcome(enum.StrEnum):
    completed = "completed"
    replan_required = "replan_required"
    aborted = "aborted"
    failed = "failed"


class BinInfo(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    type: str | None = None
    pose: PoseMsg | None = None


class ViewpointResult(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    index: int
    camera_pose: PoseMsg | None = None
    label: Literal["clean", "dirty"] | None = None
    p_dirty: float | None = None
    uncertain: bool = False
    error: str | None = None
    p_supervised: float | None = None
    anomaly_z: float | None = None
    model_id: str | None = Field(
        default=None, max_length=256, description="the classifier model that decided this view (ClassifyReply)"
    )
    heatmap: str | None = Field(default=None, description="per-patch p_dirty, as in ClassifyReply")
    heat_grid: int | None = None
    relook_of: int | None = Field(default=None, description="index of the uncertain viewpoint this view re-looks at")
    station: int | None = Field(default=None, description="whole-bin cycle: the station (plan rank) it was taken at")
    surface: Surface | None = Field(default=None, description="whole-bin cycle: the surface it inspects")
    wash_round: int | None = Field(default=None, description="wash_and_verify: the round this view re-inspects after")
    decided_by: Literal["reference", "detector", "model"] | None = Field(
        default=None, description="what decided this view (ClassifyReply.decided_by)"
    )
    reference_reason: ReferenceReason | None = Field(
        default=None,
        description="why the view was (aligned) or was not judged against its reference; None: its plan has no set",
    )


class StationResult(BaseModel):
    """What a whole-bin cycle did at one station (CycleResult.stations, in visiting order)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    station: int = Field(ge=0, description="the station's rank in the whole-bin plan")
    base_pose: PoseMsg | None = Field(default=None, description="planned base pose, bin frame (frame_id 'bin')")
    bin_pose_source: Literal["measured", "base_odometry", "carried_over"] | None = Field(
        default=None,
        description="measured from the board here; base_odometry: the pose measured at an earlier station carried "
        "through the base's reported motion (board not visible); carried_over: the planned station pose (board not "
        "visible, the base reports no pose)",
    )
    plan_ids: dict[str, str] = Field(default_factory=dict, description="surface -> plan used")
    adjusted: dict[str, bool] = Field(default_factory=dict, description="surface -> viewpoints re-expressed")
    viewpoints: dict[str, int] = Field(default_factory=dict, description="surface -> planned viewpoints")
    refused: dict[str, int] = Field(default_factory=dict, description="surface -> viewpoints the arm refused")
    coverage: dict[str, float | None] = Field(default_factory=dict, description="surface -> area fraction seen here")
    reason: str | None = None


DecisionPath = Literal["references", "enrolled", "shipped"]
"""What a surface's views were judged against (:attr:`CycleResult.decision_path`)."""


class CommissionResult(BaseModel):
    """What a commissioning cycle (Start ``mode=commission``) left: one reference per viewpoint, enrolled detectors."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    bin_type: str = Field(max_length=128)
    version: int = Field(ge=1, description="the reference set's version for this bin type (1, 2, …)")
    manifest: str = Field(max_length=4096, description="the set's manifest.json (relative to the config root)")
    manifest_sha256: str = Field(pattern=r"^[0-9a-f]{64}$", description="also in the cycle's MCAP, hash-chained")
    references: int = Field(ge=0, description="viewpoints with a reference image")
    plan_ids: list[str] = Field(default_factory=list, max_length=64)
    declared_by: str = Field(max_length=MAX_USER_CHARS, description="the user who declared the bin clean")
    enrolled: dict[Surface, str] = Field(
        default_factory=dict, description="surface -> enrolled detector file (in the set's folder), now in use"
    )
    problems: dict[str, str] = Field(default_factory=dict, description="surface -> why it was not enrolled")


class CycleResult(WireMessage):
    type: Literal["cellctl/CycleResult"] = "cellctl/CycleResult"
    v: Literal[1] = 1
    cycle_id: str
    outcome: CycleOutcome
    reason: str | None = None
    bin: BinInfo = Field(default_factory=BinInfo)
    plan_id: str | None = None
    plan_adjusted: bool | None = Field(default=None, description="viewpoints re-expressed at the measured bin pose")
    planner_job_id: str | None = None
    verdict: Verdict | None = Field(
        default=None,
        description="completed cycles: clean, dirty (dirt seen, however little of the bin was), or incomplete (no "
        "dirt seen, but some surface seen less than min_seen_fraction; `reason` gives the fractions)",
    )
    viewpoints: list[ViewpointResult] = Field(default_factory=list)
    coverage: float | None = None
    dirt_map: dict[str, Any] | None = None
    log: str | None = None
    timing: dict[str, Any] | None = Field(default=None, description="seconds per step and in worker requests")
    started: str | None = None
    whole_plan_id: str | None = Field(default=None, description="whole-bin cycle: the whole-bin plan it followed")
    coverage_by_surface: dict[str, float | None] | None = Field(
        default=None, description="area fraction of each surface seen (a whole-bin cycle: all stations)"
    )
    min_seen_fraction: dict[str, float] | None = Field(
        default=None,
        description="classifier.verdict.min_seen_fraction: the share of each surface `clean` needed (incomplete below)",
    )
    stations: list[StationResult] | None = Field(default=None, description="whole-bin cycle: per station")
    modelled_cycle_s: float | None = Field(
        default=None, description="whole-bin cycle: the plan's modelled cycle time at the arm's real limits"
    )
    classifier_models: list[str] | None = Field(
        default=None,
        max_length=16,
        description="the models that decided the cycle's views: <surface>-detect-<sha12> (shipped detector), "
        "<surface>-enrolled-<sha12> (site-enrolled, classifier.detector_files), <surface>-<arch>-… (whole-image)",
    )
    decision_path: dict[Surface, DecisionPath] | None = Field(
        default=None,
        description="per surface, what the views were judged against: references (views of the surface were decided "
        "by the comparison with their commissioned reference: ViewpointResult.decided_by says which), enrolled "
        "(none: a site-enrolled detector), shipped (none: the shipped model)",
    )
    reference_version: int | None = Field(
        default=None, ge=1, description="the reference set (of the bin type) the references came from"
    )
    commission: CommissionResult | None = Field(
        default=None, description="mode commission: the reference set written and the detectors enrolled"
    )
    finished: str = Field(default_factory=now_iso)
    wash: WashResult | None = Field(default=None, description="mode wash_and_verify: the rounds and the wash verdict")
    viewpoints_omitted: int | None = Field(
        default=None,
        ge=0,
        description="views left out of this message (heat maps first, then clean views) to fit the wire's size limit; "
        "the cycle's MCAP (`log`) records every one",
    )
