"""The planner's ops: planning jobs, the plan lookup, and the planner pool's queue (docs/deploy/README.md)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, FiniteFloat

from cellctl.messages.base import Joints, PoseMsg, WireMessage
from cellctl.surface import Surface


class PlanJobRequest(WireMessage):
    """Submit an offline planning job for a bin type at a measured bin pose."""

    type: Literal["cellctl/PlanJobRequest"] = "cellctl/PlanJobRequest"
    v: Literal[1] = 1
    bin_type: str
    bin_pose: PoseMsg = Field(description="bin pose in the robot base frame")
    surface: Surface = "external"
    seed_pct: float = Field(default=10.0, gt=0.0, le=100.0)
    mode: Literal["fast", "paper"] = "fast"
    seed: int = 0
    q_start: list[FiniteFloat] | None = Field(
        default=None, min_length=6, max_length=6, description="robot joints now (rad): where the tour starts"
    )
    whole: bool = Field(
        default=False,
        description="plan the whole bin (stations, both surfaces; bin_pose, surface and q_start are not used)",
    )


class PlanJobReply(WireMessage):
    type: Literal["cellctl/PlanJobReply"] = "cellctl/PlanJobReply"
    v: Literal[1] = 1
    job_id: str = Field(max_length=128)
    state: Literal["queued", "running", "done", "failed"] = "queued"
    plan_id: str | None = None
    reason: str | None = None


class PlanJobProgress(WireMessage):
    type: Literal["cellctl/PlanJobProgress"] = "cellctl/PlanJobProgress"
    v: Literal[1] = 1
    job_id: str
    stage: str
    fraction: float = Field(ge=0.0, le=1.0)
    state: Literal["queued", "running", "done", "failed"] = "running"
    message: str | None = None
    plan_id: str | None = None


class PlanJobQuery(WireMessage):
    """Ask for the state of a planning job (answered with PlanJobReply)."""

    type: Literal["cellctl/PlanJobQuery"] = "cellctl/PlanJobQuery"
    v: Literal[1] = 1
    job_id: str


class PlannedViewpoint(BaseModel):
    """One viewpoint of a plan, in visiting order, expressed for the measured bin pose."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    index: int = Field(ge=0)
    camera_pose: PoseMsg
    joints: Joints
    faces: list[int] = Field(default_factory=list, description="mesh face ids visible from here")


class PlanLookupRequest(WireMessage):
    """Cache lookup + tolerance check + adjustment, done by a planner worker."""

    type: Literal["cellctl/PlanLookupRequest"] = "cellctl/PlanLookupRequest"
    v: Literal[1] = 1
    bin_type: str
    bin_pose: PoseMsg = Field(description="measured bin pose in the robot base frame")
    surface: Surface = "external"
    all_reachable: bool = Field(
        default=False, description="data collection: every reachable viewpoint (paper §IV-B2), not only the tour"
    )
    whole: bool = Field(default=False, description="whole-bin cycle: also answer the newest whole-bin plan's stations")


class StationInfo(BaseModel):
    """One station of a whole-bin plan, as the cycle needs it (PlanLookupReply.stations)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    station: int = Field(ge=0, description="rank: visiting order in the plan")
    base_pose: PoseMsg = Field(description="T_bin_base: where the base parks, bin frame (frame_id 'bin')")
    observation_index: int | None = Field(
        default=None, ge=0, description="observation pose that sees the board from here; None: the board is not visible"
    )
    identify_reason: str | None = None
    plans: dict[str, str] = Field(default_factory=dict, description="surface -> plan id (surfaces with viewpoints)")
    viewpoints: dict[str, int] = Field(default_factory=dict)


class PlanLookupReply(WireMessage):
    type: Literal["cellctl/PlanLookupReply"] = "cellctl/PlanLookupReply"
    v: Literal[1] = 1
    hit: bool
    reason: str | None = None
    plan_id: str | None = Field(default=None, max_length=256)
    viewpoints: list[PlannedViewpoint] = Field(default_factory=list)
    coverage: FiniteFloat | None = Field(default=None, ge=0.0, le=1.0)
    adjusted: bool = False
    translation_mm: FiniteFloat | None = None
    rotation_deg: FiniteFloat | None = None
    mesh_faces: int | None = Field(default=None, ge=0)
    whole_plan_id: str | None = Field(default=None, max_length=256, description="request.whole: the whole-bin plan")
    stations: list[StationInfo] = Field(default_factory=list, description="request.whole: its stations, in order")
    station: int | None = Field(
        default=None, description="request.whole: the station whose planned base pose is nearest the measured one"
    )
    cycle_time_s: FiniteFloat | None = Field(default=None, description="request.whole: the plan's modelled cycle")


class PoolClaim(WireMessage):
    """A pool worker asks the job queue for its next job; it holds the job while its liveliness lives."""

    type: Literal["cellctl/PoolClaim"] = "cellctl/PoolClaim"
    v: Literal[1] = 1
    instance: str = Field(pattern=r"^[a-z][a-z0-9_-]{0,63}$")


class PoolAssignment(WireMessage):
    """The queue's answer to a claim: one job for this worker alone, or none (``job_id`` None)."""

    type: Literal["cellctl/PoolAssignment"] = "cellctl/PoolAssignment"
    v: Literal[1] = 1
    job_id: str | None = Field(default=None, max_length=128)
    cell_id: str | None = Field(default=None, max_length=64)
    attempt: int = Field(default=0, ge=0)
    request: PlanJobRequest | None = None
    reason: str | None = None


class PoolDone(WireMessage):
    """A pool worker reports a claimed job finished (answered with the job's PlanJobReply)."""

    type: Literal["cellctl/PoolDone"] = "cellctl/PoolDone"
    v: Literal[1] = 1
    job_id: str = Field(max_length=128)
    instance: str = Field(pattern=r"^[a-z][a-z0-9_-]{0,63}$")
    state: Literal["done", "failed"]
    plan_id: str | None = None
    reason: str | None = None


class PoolStatsRequest(WireMessage):
    type: Literal["cellctl/PoolStatsRequest"] = "cellctl/PoolStatsRequest"
    v: Literal[1] = 1


class PoolStats(WireMessage):
    """The job queue's counters: each job should be planned exactly once (``planned_twice`` 0)."""

    type: Literal["cellctl/PoolStats"] = "cellctl/PoolStats"
    v: Literal[1] = 1
    submitted: int = 0
    planned: int = 0
    failed: int = 0
    requeued: int = 0
    planned_twice: int = 0
    queued: int = 0
    running: int = 0
    per_worker: dict[str, int] = Field(default_factory=dict, description="jobs planned per worker instance")
    workers: list[str] = Field(default_factory=list, description="pool workers alive now")
