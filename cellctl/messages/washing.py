"""Washing: the robot op ``wash``, the planner op ``wash_plan``, and the wash-and-verify result."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, FiniteFloat

from cellctl.messages.base import Joints, PoseMsg, WireMessage
from cellctl.seen import Verdict


class WashSweep(BaseModel):
    """One continuous tool path of the nozzle: joint waypoints followed in order, ``passes`` times
    (back and forth)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    joints: list[Joints] = Field(min_length=1, max_length=2000)
    passes: int = Field(default=1, ge=1, le=20)
    region: int | None = Field(default=None, description="the dirty region it washes (for the logs)")


class WashRequest(WireMessage):
    """Run wash sweeps (op ``robot/wash``): each sweep's start is reached by a planned
    collision-free motion, then its waypoints are followed as one continuous trajectory."""

    type: Literal["cellctl/WashRequest"] = "cellctl/WashRequest"
    v: Literal[1] = 1
    sweeps: list[WashSweep] = Field(min_length=1, max_length=2000)
    round: int = Field(default=1, ge=1, le=100, description="wash-and-verify round (for the logs)")


class WashReply(WireMessage):
    type: Literal["cellctl/WashReply"] = "cellctl/WashReply"
    v: Literal[1] = 1
    sweeps_run: int = Field(ge=0)
    passes_run: int = Field(ge=0)
    joints: Joints
    path_length_rad: FiniteFloat = 0.0
    duration_s: FiniteFloat = 0.0


class WashPlanRequest(WireMessage):
    """Plan a wash from a cycle's dirt map (planner op ``wash_plan``; the planner worker owns the
    heavy planning stack, the supervisor never imports it)."""

    type: Literal["cellctl/WashPlanRequest"] = "cellctl/WashPlanRequest"
    v: Literal[1] = 1
    bin_type: str = Field(min_length=1, max_length=128)
    stations: list[PoseMsg] = Field(min_length=1, max_length=36, description="base poses T_bin_base (frame 'bin')")
    q_start: Joints = Field(description="the arm's joints now: the tour starts there")
    dirt_map: dict[str, Any] | None = Field(description="the CycleResult's dirt_map (face_p or seen_dirty)")
    threshold: float = Field(default=0.5, gt=0, lt=1)
    margin_m: float = Field(default=0.02, ge=0, le=0.3)
    seed: int = Field(default=0, ge=0, lt=2**63)
    round: int = Field(default=1, ge=1, le=100)


class PlannedSweep(BaseModel):
    """One sweep of a wash plan: joint waypoints, passes, and where its jet's spot runs (bin frame)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    joints: list[Joints] = Field(min_length=1, max_length=2000)
    passes: int = Field(default=1, ge=1, le=20)
    region: int = 0
    station: int = 0
    faces: list[int] = Field(default_factory=list, description="target faces it sprays")
    spots: list[tuple[FiniteFloat, FiniteFloat, FiniteFloat]] = Field(default_factory=list)
    axes: list[tuple[FiniteFloat, FiniteFloat, FiniteFloat]] = Field(default_factory=list)


class UnwashablePiece(BaseModel):
    """A piece of a target region no sweep sprays, and why."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    region: int
    faces: list[int]
    area_m2: float
    reason: str


class WashPlanReply(WireMessage):
    """The planned sweeps in execution order and what they cover (face ids of the bin mesh)."""

    type: Literal["cellctl/WashPlanReply"] = "cellctl/WashPlanReply"
    v: Literal[1] = 1
    sweeps: list[PlannedSweep] = Field(default_factory=list)
    reason: str | None = Field(default=None, description="nothing to do, or nothing can be done: no motion")
    dirty: list[int] = Field(default_factory=list)
    targets: list[int] = Field(default_factory=list)
    covered: list[int] = Field(default_factory=list)
    washed: list[int] = Field(default_factory=list)
    unwashable: list[UnwashablePiece] = Field(default_factory=list)
    summary: dict[str, Any] = Field(default_factory=dict, description="counts, areas, stage times (WashPlan.summary)")
    plan_s: float = 0.0
    cpu_s: float = 0.0


class WashRound(BaseModel):
    """One wash-and-verify round as the CycleResult records it (areas in m²)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    round: int
    dirty_faces_before: int
    dirty_m2_before: float
    sweeps_planned: int
    sweeps_run: int
    passes_run: int
    washed_m2: float
    covered_m2: float
    unwashable: list[dict[str, Any]] = Field(default_factory=list, description="target pieces no nozzle pose reaches")
    sweeps_refused: list[dict[str, Any]] = Field(default_factory=list, description="sweeps the robot refused, why")
    reinspected_views: int = 0
    dirty_faces_after: int | None = None
    dirty_m2_after: float | None = None
    plan_s: float = 0.0
    plan_cpu_s: float = 0.0
    pictures: list[str] = Field(
        default_factory=list, description="the round's pictures, in <cycle_id>.wash/ beside the log"
    )
    reason: str | None = None


class WashResult(BaseModel):
    """The wash-and-verify outcome: ``clean``/``dirty`` after the rounds, and what is left."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    verdict: Verdict | None = None
    reason: str | None = Field(
        default=None,
        description="why the bin ends dirty (unwashable, rounds exhausted) or incomplete (too little seen)",
    )
    rounds: list[WashRound] = Field(default_factory=list)
    remaining_faces: list[int] = Field(default_factory=list, description="faces still dirty at the end")
    remaining_m2: float = 0.0
    unwashable: list[dict[str, Any]] = Field(default_factory=list, description="dirt no nozzle pose reaches, why")
    seen_fraction: float | None = Field(
        default=None,
        ge=0.0,
        le=1.0,
        description="share of the bin's area (both surfaces) the scan and the re-inspections saw: what `clean` covers",
    )
    min_seen_fraction: float | None = Field(
        default=None, ge=0.0, le=1.0, description="wash.min_seen_fraction: `clean` needs seen_fraction at least this"
    )
