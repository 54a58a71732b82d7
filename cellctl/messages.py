"""Every wire message of cellctl as a typed, versioned model (wire contract v1).

Control payloads are JSON objects with ``"type"`` (``"cellctl/<Name>"``) and ``"v"``.
Images travel as encoded bytes (PNG/JPEG) in the payload, with their message (e.g.
:class:`CaptureReply`) as a JSON attachment. ``cellctl schema`` prints the JSON Schemas.

Add a message: subclass :class:`WireMessage`, give it ``type: Literal["cellctl/Name"]`` and
``v: Literal[1]``, list it in :data:`MESSAGE_TYPES`. Changing a field of an existing message
is a contract change: bump ``v`` and keep decoding the old version.
"""

from __future__ import annotations

import datetime as _dt
import enum
from collections.abc import Mapping
from typing import Annotated, Any, Literal, cast, get_args

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, field_validator, model_validator

from cellctl.seen import Verdict
from cellctl.surface import SURFACES, Surface

__all__ = [
    "MESSAGE_TYPES",
    "Ack",
    "ApproachReply",
    "Admin",
    "ApproachRequest",
    "BinInfo",
    "CaptureReply",
    "CaptureRequest",
    "ClassifierModel",
    "ClassifierModels",
    "ClassifierModelsRequest",
    "ClassifyReference",
    "ClassifyReply",
    "ClassifyRequest",
    "Command",
    "CommandName",
    "CycleOutcome",
    "CycleResult",
    "CommissionResult",
    "DecisionPath",
    "ReferenceReason",
    "START_MODES",
    "StartMode",
    "EnrollReply",
    "EnrollRequest",
    "ErrorReply",
    "Event",
    "FaultCondition",
    "FaultReport",
    "EventLevel",
    "Intrinsics",
    "JointState",
    "LastCycle",
    "MoveReply",
    "MoveRequest",
    "PackMLCommand",
    "PlanJobProgress",
    "PlanJobQuery",
    "PlanLookupReply",
    "PlanLookupRequest",
    "PlannedViewpoint",
    "PlanJobReply",
    "PlanJobRequest",
    "PoolAssignment",
    "PoolClaim",
    "PoolDone",
    "PoolStats",
    "PoolStatsRequest",
    "PoseMsg",
    "RobotMaintenanceReply",
    "RobotMaintenanceRequest",
    "RobotState",
    "RobotStateRequest",
    "SimScenarioRequest",
    "SimState",
    "SimStateRequest",
    "StartParams",
    "StationInfo",
    "StationResult",
    "Status",
    "StopRequest",
    "UnitMode",
    "UnitModeName",
    "ViewpointResult",
    "PlannedSweep",
    "UnwashablePiece",
    "WashPlanReply",
    "WashPlanRequest",
    "WashReply",
    "WashRequest",
    "WashResult",
    "WashRound",
    "WashSweep",
    "SprayPassMsg",
    "WireMessage",
    "now_iso",
]

WIRE_VERSION = 1

ROBOT_JOINTS = 6
"""Joint count of the arm (UR10e); joint vectors on the wire have exactly this many entries."""

Joints = Annotated[list[FiniteFloat], Field(min_length=ROBOT_JOINTS, max_length=ROBOT_JOINTS)]
"""Joint positions in radians; NaN/inf or a wrong length is refused when the message is decoded."""


def now_iso() -> str:
    """UTC time as ISO-8601 with milliseconds, the stamp format of every message."""
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


class WireMessage(BaseModel):
    """Base of every wire message: frozen, strict about unknown fields."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    type: str
    v: int


class PoseMsg(BaseModel):
    """A pose: position in metres, orientation as a unit quaternion ``xyzw``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    position: tuple[FiniteFloat, FiniteFloat, FiniteFloat]
    orientation: tuple[FiniteFloat, FiniteFloat, FiniteFloat, FiniteFloat] = (0.0, 0.0, 0.0, 1.0)
    frame_id: str = Field(default="base", max_length=64)

    @field_validator("orientation")
    @classmethod
    def _rotation(cls, q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        # Readers normalise the quaternion; one of (near) zero length has no direction to normalise to.
        if sum(x * x for x in q) < 1e-12:
            raise ValueError(f"orientation {q} is not a rotation: expected a unit quaternion xyzw")
        return q

    @classmethod
    def from_matrix(cls, T: Any, frame_id: str = "base") -> PoseMsg:
        from cellctl.geometry.transforms import pose_from_transform

        p, q = pose_from_transform(np.asarray(T))
        return cls(position=p, orientation=q, frame_id=frame_id)

    def matrix(self) -> np.ndarray:
        from cellctl.geometry.transforms import transform_from_pose

        return transform_from_pose((self.position, self.orientation))


# --- PackML command topic -------------------------------------------------------------------


class PackMLCommand(enum.IntEnum):
    """PackML commands with their PackTags ``CntrlCmd`` codes."""

    reset = 1
    start = 2
    stop = 3
    hold = 4
    unhold = 5
    suspend = 6
    unsuspend = 7
    abort = 8
    clear = 9
    complete = 10


class UnitMode(enum.IntEnum):
    """PackML unit modes with their PackTags ``UnitModeCurrent`` / ``UnitModeRequested`` codes."""

    production = 1
    maintenance = 2
    manual = 3

    @property
    def wire_name(self) -> UnitModeName:
        """The name on the wire (``Command.unit_mode``, ``Ack``/``Status.unit_mode``)."""
        return cast(UnitModeName, self.name)


UnitModeName = Literal["production", "maintenance", "manual"]
CommandName = Literal["reset", "start", "stop", "hold", "unhold", "suspend", "unsuspend", "abort", "clear", "complete"]
"""A PackML command's name on the wire (``Command.command``)."""

MAX_USER_CHARS = 64
MAX_REQUEST_ID_CHARS = 128


def _strict_code(v: Any, field: str, allowed: str) -> Any:
    # Lax validation would read true as 1 and "2" as 2: a PLC sending those is broken.
    if isinstance(v, bool | str):
        raise ValueError(f"{field} must be an integer code {allowed}, got {type(v).__name__} {v!r}")
    return v


class Command(WireMessage):
    """A PackML command or a unit-mode change request from a PLC or operator on ``cell/<id>/cmd``.

    Exactly one of ``command`` (lower-case name), ``cntrl_cmd`` (PackTags code), ``unit_mode``
    (mode name), ``unit_mode_code`` (PackTags UnitMode code) or ``base_parked`` (a manual base's
    confirmation) is given.
    """

    type: Literal["cellctl/Command"] = "cellctl/Command"
    v: Literal[1] = 1
    command: CommandName | None = None
    cntrl_cmd: int | None = Field(default=None, description="PackTags CntrlCmd code 1..10")
    unit_mode: UnitModeName | None = Field(default=None, description="requested PackML unit mode")
    unit_mode_code: int | None = Field(default=None, description="PackTags UnitModeRequested code 1..3")
    base_parked: int | None = Field(
        default=None, ge=0, description="manual base: the operator/PLC confirms the base is parked at this station"
    )
    request_id: str | None = Field(default=None, max_length=MAX_REQUEST_ID_CHARS)
    user: str | None = Field(
        default=None, max_length=MAX_USER_CHARS, description="who sent it, e.g. 'hmi:alice' (printable)"
    )
    params: dict[str, Any] = Field(default_factory=dict)
    stamp: str | None = Field(
        default=None,
        description="when the sender sent it (ISO-8601 with a UTC offset); the supervisor refuses a stale one",
    )

    @field_validator("stamp")
    @classmethod
    def _aware_time(cls, v: str | None) -> str | None:
        if v is not None:
            try:
                t = _dt.datetime.fromisoformat(v)
            except ValueError:
                raise ValueError(f"stamp {v[:40]!r} is not an ISO-8601 time, e.g. {now_iso()!r}") from None
            if t.tzinfo is None:
                raise ValueError(f"stamp {v[:40]!r} has no UTC offset, e.g. {now_iso()!r}")
        return v

    @field_validator("cntrl_cmd", mode="before")
    @classmethod
    def _integer_code(cls, v: Any) -> Any:
        return _strict_code(v, "cntrl_cmd", "1..10")

    @field_validator("unit_mode_code", mode="before")
    @classmethod
    def _integer_mode(cls, v: Any) -> Any:
        return _strict_code(v, "unit_mode_code", "1..3")

    @field_validator("base_parked", mode="before")
    @classmethod
    def _station(cls, v: Any) -> Any:
        return _strict_code(v, "base_parked", "(a station number >= 0)")

    @field_validator("user")
    @classmethod
    def _printable(cls, v: str | None) -> str | None:
        if v is not None and not v.isprintable():
            raise ValueError(f"user {v[:MAX_USER_CHARS]!r} must be printable characters only")
        return v

    @model_validator(mode="after")
    def _one_command(self) -> Command:
        state_cmd = [f for f in ("command", "cntrl_cmd") if getattr(self, f) is not None]
        mode_cmd = [f for f in ("unit_mode", "unit_mode_code") if getattr(self, f) is not None]
        if self.base_parked is not None:
            if state_cmd or mode_cmd:
                raise ValueError(f"a base confirmation ('base_parked') comes alone, got it with {state_cmd + mode_cmd}")
            return self
        if mode_cmd and not state_cmd:
            if len(mode_cmd) == 2:
                raise ValueError("give exactly one of 'unit_mode' (a mode name) or 'unit_mode_code' (1..3), got both")
            if self.unit_mode_code is not None and self.unit_mode_code not in {m.value for m in UnitMode}:
                raise ValueError(
                    f"unit_mode_code {self.unit_mode_code!r} is unknown; expected one of "
                    + ", ".join(f"{m.value} {m.name}" for m in UnitMode)
                )
            return self
        if mode_cmd:
            raise ValueError(
                f"a command carries either a PackML command or a unit mode change, got both {state_cmd + mode_cmd}"
            )
        if len(state_cmd) != 1:
            raise ValueError(
                "give exactly one of 'command' (a PackML command name) or 'cntrl_cmd' (1..10), or a unit mode"
                f" change ('unit_mode' or 'unit_mode_code' 1..3); got {state_cmd or 'neither'}"
            )
        if self.cntrl_cmd is not None and self.cntrl_cmd not in {c.value for c in PackMLCommand}:
            raise ValueError(
                f"cntrl_cmd {self.cntrl_cmd!r} is unknown; expected one of "
                + ", ".join(f"{c.value} {c.name}" for c in PackMLCommand)
            )
        return self

    @property
    def requested_mode(self) -> UnitMode | None:
        """The unit mode this command asks for, whichever way it was given; None for a PackML command."""
        if self.unit_mode is not None:
            return UnitMode[self.unit_mode]
        if self.unit_mode_code is not None:
            return UnitMode(self.unit_mode_code)
        return None

    @property
    def name(self) -> str:
        """The command's lower-case PackML name, whichever way it was given ('unit_mode' for a mode change)."""
        if self.command is not None:
            return self.command
        if self.cntrl_cmd is not None:
            return PackMLCommand(self.cntrl_cmd).name
        if self.base_parked is not None:
            return "base_parked"
        return "unit_mode"


START_PARAM_NAMES = ("mode", "label", "surface", "perturb_m", "seed", "dataset")
StartMode = Literal["evaluate", "collect", "wash_and_verify", "commission"]
START_MODES: tuple[str, ...] = get_args(StartMode)
"""The Start param ``mode`` values (``commission``: added in v1, additive: older senders never send it)."""


class StartParams(WireMessage):
    """The params of a Start command (``Command.params``), as the supervisor checks them.

    On the wire they travel as a plain object inside the Command (no ``type``/``v`` there);
    this model is their schema, checked by :meth:`from_params` before the cycle starts.
    """

    type: Literal["cellctl/StartParams"] = "cellctl/StartParams"
    v: Literal[1] = 1
    mode: StartMode = Field(
        default="evaluate",
        description="evaluate: inspect; collect: store labelled images; wash_and_verify: inspect, wash the dirty "
        "regions, re-inspect them, up to wash.max_rounds rounds; commission (maintenance unit mode, a named user): "
        "the bin is declared clean, each view becomes the reference of its viewpoint and each surface's detector "
        "is enrolled from the views",
    )
    label: Literal["clean", "dirty"] | None = Field(default=None, description="collect mode: the class of this bin")
    surface: Surface | None = Field(
        default=None, description="surface to inspect; default planner.surface of the config"
    )
    perturb_m: float = Field(default=0.0, ge=0.0, le=0.1, description="collect mode: random camera offset (m)")
    seed: int = Field(default=0, ge=0, lt=2**63, description="seed of the perturbation")
    dataset: str | None = Field(
        default=None,
        max_length=64,
        description="collect mode: dataset folder name under classifier.dataset_dir (letters, digits, '.', '_', '-')",
    )

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> StartParams:
        """Check a Start command's params; raise ProtocolError naming the bad value."""
        from cellctl.classify.collect import DATASET_NAME
        from cellctl.errors import ProtocolError

        unknown = set(params) - set(START_PARAM_NAMES)
        if unknown:
            raise ProtocolError(f"unknown start params {sorted(unknown)}; allowed: {sorted(START_PARAM_NAMES)}")
        mode = params.get("mode", "evaluate")
        if mode not in START_MODES:
            known = ", ".join(map(repr, START_MODES[:-1])) + f" or {START_MODES[-1]!r}"
            raise ProtocolError(f"start param mode={mode!r:.80}; expected {known}")
        label = params.get("label")
        if mode == "collect" and label not in ("clean", "dirty"):
            raise ProtocolError(f"start param label={label!r}; collect mode needs label 'clean' or 'dirty'")
        if "surface" in params and params["surface"] not in SURFACES:
            expected = " or ".join(repr(s) for s in SURFACES)
            raise ProtocolError(f"start param surface={params['surface']!r}; expected {expected}")
        perturb = params.get("perturb_m", 0.0)
        if isinstance(perturb, bool) or not isinstance(perturb, int | float) or not 0 <= perturb <= 0.1:
            raise ProtocolError(f"start param perturb_m={perturb!r:.80}; expected a number in [0, 0.1] m")
        seed = params.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
            # numpy seeds the perturbation with it: a negative or huge seed would fail mid-cycle
            raise ProtocolError(f"start param seed={seed!r:.80}; expected an integer in [0, 2**63)")
        dataset = params.get("dataset")
        if "dataset" in params and not (isinstance(dataset, str) and DATASET_NAME.fullmatch(dataset)):
            raise ProtocolError(
                f"start param dataset={dataset!r:.80}; expected a dataset name (letters, digits, '.', '_', '-';"
                " at most 64, no path) stored under classifier.dataset_dir"
            )
        return cls(
            mode=mode,
            # evaluate mode ignores a label (accepted as before, never used)
            label=label if mode == "collect" else None,
            surface=params.get("surface"),
            perturb_m=float(perturb),
            seed=seed,
            dataset=dataset,
        )

    def as_params(self) -> dict[str, Any]:
        """The params as a Command carries them (only those set)."""
        return self.model_dump(exclude={"type", "v"}, exclude_none=True)


class Ack(WireMessage):
    """Reply to every command: accepted or not, with the reason and the state after it."""

    type: Literal["cellctl/Ack"] = "cellctl/Ack"
    v: Literal[1] = 1
    request_id: str | None
    command: str | None = None
    accepted: bool
    reason: str | None = None
    state: str
    user: str | None = Field(default=None, description="the Command's user, echoed")
    unit_mode: UnitModeName | None = Field(default=None, description="the unit mode after handling the command")


class LastCycle(BaseModel):
    """The last finished cycle, as Status.admin reports it."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    cycle_id: str
    outcome: str
    verdict: str | None = None
    coverage: float | None = None
    finished: str
    coverage_by_surface: dict[str, float | None] | None = Field(
        default=None, description="area fraction of each surface seen (CycleResult.coverage_by_surface)"
    )
    min_seen_fraction: dict[str, float] | None = Field(
        default=None, description="the share of each surface `clean` needed (verdict `incomplete` below it)"
    )
    decision_path: dict[str, str] | None = Field(
        default=None, description="what each surface was judged against (CycleResult.decision_path)"
    )

    @classmethod
    def of(cls, res: CycleResult) -> LastCycle:
        """The Admin view of a finished cycle (the daemon's Status and the OPC UA gateway read the same)."""
        return cls(
            cycle_id=res.cycle_id,
            outcome=res.outcome.value,
            verdict=res.verdict,
            coverage=res.coverage,
            finished=res.finished,
            coverage_by_surface=res.coverage_by_surface,
            min_seen_fraction=res.min_seen_fraction,
            decision_path={k: v for k, v in res.decision_path.items()} if res.decision_path else None,
        )


MAX_WARNINGS = 20


class Admin(BaseModel):
    """PackML Admin / PackTags counters and reasons; counters persist across restarts (the cycle index)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    prod_processed_count: int = Field(default=0, ge=0, description="bins inspected: cycles completed (any verdict)")
    prod_defective_count: int = Field(default=0, ge=0, description="of those, verdict dirty")
    stop_reason: str | None = Field(default=None, description="why the cell last went to Stopped/Aborted/Held")
    warnings: list[str] = Field(default_factory=list, max_length=MAX_WARNINGS)
    last_cycle: LastCycle | None = None


class Status(WireMessage):
    """The cell's PackML status, published on every change and at 1 Hz."""

    type: Literal["cellctl/Status"] = "cellctl/Status"
    v: Literal[1] = 1
    cell: str
    state: str
    state_code: int
    step: str | None = None
    cycle_id: str | None = None
    available_commands: list[str]
    unit_mode: UnitModeName = "production"
    unit_mode_code: int = Field(default=1, ge=1, le=3, description="PackTags UnitModeCurrent")
    last_error: str | None = None
    workers: dict[str, bool] = Field(default_factory=dict, description="liveliness of each worker role")
    admin: Admin = Field(default_factory=Admin)
    stamp: str = Field(default_factory=now_iso)


class EventLevel(enum.IntEnum):
    """Levels as foxglove.Log uses them."""

    debug = 1
    info = 2
    warning = 3
    error = 4
    fatal = 5


class Event(WireMessage):
    type: Literal["cellctl/Event"] = "cellctl/Event"
    v: Literal[1] = 1
    level: Literal["debug", "info", "warning", "error", "fatal"] = "info"
    text: str
    cycle_id: str | None = None
    stamp: str = Field(default_factory=now_iso)


FaultCondition = Literal[
    "protective_stop",
    "emergency_stop",
    "safeguard_stop",
    "safety_fault",
    "safety_violation",
    "reduced_mode",
    "robot_mode",
    "lost_connection",
    "stall",
    "program_stopped",
    "other",
]
"""What a worker's fault is: the controller's safety state (``*_stop``, ``safety_*``, ``reduced_mode``),
a robot mode other than RUNNING, the link (``lost_connection``), a controller that stopped answering
(``stall``: no data, a call that does not return), or its control program stopping during a motion."""


class FaultReport(WireMessage):
    """A worker's fault report on ``cell/<id>/<role>/fault`` (today: the UR robot worker).

    ``active``: published just before the worker withdraws its liveliness token, so the supervisor
    names the fault as the reason of the loss; ``active`` false: an operator cleared it (the token
    comes back). Subscribers also accept the first form of the report, an error :class:`Event` with
    text ``"<role> fault: <detail>"``, from workers of before this message.
    """

    type: Literal["cellctl/FaultReport"] = "cellctl/FaultReport"
    v: Literal[1] = 1
    role: str = Field(pattern=r"^[a-z][a-z_]{0,31}$", description="the reporting worker's role")
    active: bool = Field(default=True, description="False: cleared by an operator's maintenance")
    condition: FaultCondition
    detail: str = Field(min_length=1, description="what the worker saw, e.g. 'protective stop'")
    robot_mode: str | None = Field(default=None, description="ur: the controller's robot mode, e.g. RUNNING")
    safety_mode: str | None = Field(default=None, description="ur: the controller's safety mode, e.g. PROTECTIVE_STOP")
    safety_status_bits: int | None = Field(default=None, ge=0, description="ur: RTDE safety_status_bits")
    safety_flags: list[str] = Field(default_factory=list, description="ur: the names of the bits set")
    cycle_id: str | None = None
    stamp: str = Field(default_factory=now_iso)

    @property
    def text(self) -> str:
        """The reason text the supervisor records: ``"<role> fault: <detail>"``."""
        return f"{self.role} fault: {self.detail}"


class CycleOutcome(enum.StrEnum):
    completed = "completed"
    replan_required = "replan_required"
    aborted = "aborted"
    failed = "failed"


class BinInfo(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    type: str | None = None
    pose: PoseMsg | None = None


ReferenceReason = Literal[
    "aligned",
    "no_reference",
    "no_fusion",
    "unreadable",
    "out_of_tolerance",
    "degenerate_prior",
    "ecc_not_converged",
    "low_correlation",
    "far_from_prior",
    "small_overlap",
]
"""Why a view was (``aligned``) or was not judged against its reference: the alignment's reject reasons
(:data:`cellctl.classify.reference.REJECT_REASONS`), ``no_fusion`` (the worker has no fitted
``<surface>.reference.json``), ``unreadable`` (the stored image is missing or not the manifest's)."""


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


class EnrollRequest(WireMessage):
    """Enroll one surface's detector from a folder of clean views (``cell/<id>/classifier/enroll``).

    The folder and the file are paths on the classifier worker's host (the reference root is
    shared with the supervisor's host; the default cell runs both on one).
    """

    type: Literal["cellctl/EnrollRequest"] = "cellctl/EnrollRequest"
    v: Literal[1] = 1
    surface: Surface
    images: str = Field(max_length=4096, description="folder of the surface's clean views")
    out: str = Field(max_length=4096, description="the enrolled detector file to write, then use")


class EnrollReply(WireMessage):
    type: Literal["cellctl/EnrollReply"] = "cellctl/EnrollReply"
    v: Literal[1] = 1
    surface: Surface
    model_id: str = Field(max_length=256)
    path: str = Field(max_length=4096)
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    threshold: FiniteFloat = Field(ge=0.0, le=1.0)
    images: int = Field(ge=0)


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


# --- worker replies -------------------------------------------------------------------------


class ErrorReply(WireMessage):
    """What a worker sends with ``reply_err``: a kind and a human-readable reason."""

    type: Literal["cellctl/ErrorReply"] = "cellctl/ErrorReply"
    v: Literal[1] = 1
    kind: str = Field(description="exception class name, e.g. RobotError, ProtocolError")
    reason: str


# --- robot ----------------------------------------------------------------------------------


class JointState(WireMessage):
    type: Literal["cellctl/JointState"] = "cellctl/JointState"
    v: Literal[1] = 1
    names: list[str]
    position: list[float]
    stamp: str = Field(default_factory=now_iso)


class ApproachRequest(WireMessage):
    """Park the base beside the bin and move the arm to an observation pose."""

    type: Literal["cellctl/ApproachRequest"] = "cellctl/ApproachRequest"
    v: Literal[1] = 1
    observation_index: int = Field(default=0, ge=0, description="which observation pose (retries use the next)")
    park: bool = Field(default=True, description="False: only move the arm to the observation pose")
    base_pose: PoseMsg | None = Field(
        default=None,
        description="whole-bin station: where the base parks, in the bin frame (T_bin_base); None: the nominal park",
    )
    observe: bool = Field(
        default=True, description="False: park only, the arm stays tucked (a station that cannot see the board)"
    )


class ApproachReply(WireMessage):
    type: Literal["cellctl/ApproachReply"] = "cellctl/ApproachReply"
    v: Literal[1] = 1
    joints: Joints
    flange_pose: PoseMsg
    camera_pose: PoseMsg
    observation_index: int = 0
    base_pose: PoseMsg | None = Field(
        default=None,
        description="where the mobile base says it is parked: its localisation, frame_id 'map' (T_map_base); "
        "None: the base reports no pose",
    )


class MoveRequest(WireMessage):
    """Move to joint positions or to a camera pose (in the robot base frame)."""

    type: Literal["cellctl/MoveRequest"] = "cellctl/MoveRequest"
    v: Literal[1] = 1
    joints: Joints | None = None
    camera_pose: PoseMsg | None = None
    settle_s: float | None = Field(default=None, ge=0.0, le=60.0)

    @model_validator(mode="after")
    def _one_target(self) -> MoveRequest:
        if (self.joints is None) == (self.camera_pose is None):
            raise ValueError("give exactly one of 'joints' or 'camera_pose'")
        return self


class MoveReply(WireMessage):
    type: Literal["cellctl/MoveReply"] = "cellctl/MoveReply"
    v: Literal[1] = 1
    joints: Joints
    camera_pose: PoseMsg
    path_length_rad: FiniteFloat = 0.0
    duration_s: FiniteFloat = 0.0


class RobotStateRequest(WireMessage):
    type: Literal["cellctl/RobotStateRequest"] = "cellctl/RobotStateRequest"
    v: Literal[1] = 1


class RobotState(WireMessage):
    type: Literal["cellctl/RobotState"] = "cellctl/RobotState"
    v: Literal[1] = 1
    joints: Joints
    flange_pose: PoseMsg
    camera_pose: PoseMsg
    moving: bool = False
    speed_slider: float | None = Field(default=None, description="ur: the pendant's speed slider (0–1)")
    fault: str | None = Field(default=None, description="ur: the latched safety fault, until cleared")
    stamp: str = Field(default_factory=now_iso)


class RobotMaintenanceRequest(WireMessage):
    """An operator's explicit maintenance action on the real arm (op ``robot/maintenance``).

    Never sent by the supervisor: unlocking a protective stop needs a person who inspected its cause.
    """

    type: Literal["cellctl/RobotMaintenanceRequest"] = "cellctl/RobotMaintenanceRequest"
    v: Literal[1] = 1
    action: Literal["unlock_protective_stop", "close_safety_popup", "power_on", "brake_release", "clear_fault"]
    user: str = Field(min_length=1, description="who asked (logged)")


class RobotMaintenanceReply(WireMessage):
    type: Literal["cellctl/RobotMaintenanceReply"] = "cellctl/RobotMaintenanceReply"
    v: Literal[1] = 1
    action: str
    detail: str = Field(description="the controller's answer")
    fault: str | None = None


class StopRequest(WireMessage):
    """Stop any motion now (sent on Stop/Abort/Hold)."""

    type: Literal["cellctl/StopRequest"] = "cellctl/StopRequest"
    v: Literal[1] = 1
    reason: str = ""


# --- sim (twin only: the scenario and its ground truth; the supervisor must not use them) ---


class SimStateRequest(WireMessage):
    """Ask the sim robot worker for the current sim state (``keys.sim_state``)."""

    type: Literal["cellctl/SimStateRequest"] = "cellctl/SimStateRequest"
    v: Literal[1] = 1
    washes: bool = Field(default=False, description="also send the spray passes run so far (the camera renders them)")


class SimScenarioRequest(WireMessage):
    """Change the sim scenario at run time (op ``robot/scenario``); None leaves a field as is."""

    type: Literal["cellctl/SimScenarioRequest"] = "cellctl/SimScenarioRequest"
    v: Literal[1] = 1
    bin_type: str | None = None
    bin_xyz_yaw: tuple[float, float, float, float] | None = Field(
        default=None, description="bin footprint x, y (m), lift z (m), yaw (rad) in the world frame"
    )
    park_offset_xy_yaw: tuple[float, float, float] | None = Field(
        default=None, description="systematic parking offset x, y (m), yaw (rad) in the base frame (obstacle)"
    )
    dirty: bool | None = None
    powder_amount: float | None = Field(default=None, ge=0.0, le=1.0)
    seed: int | None = None
    repark: bool = Field(default=False, description="park the base again now (arm goes home first)")


class SimState(WireMessage):
    """The sim world now: scenario, true poses (ground truth) and the arm's joints."""

    type: Literal["cellctl/SimState"] = "cellctl/SimState"
    v: Literal[1] = 1
    bin_type: str
    bin_xyz_yaw: tuple[float, float, float, float]
    park_offset_xy_yaw: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dirty: bool
    powder_amount: float
    seed: int
    world_T_bin: PoseMsg
    world_T_base: PoseMsg
    parked: bool
    joints: list[float]
    moving: bool = False
    wash_passes: int = Field(default=0, ge=0, description="spray passes run over the bin since the scenario was set")
    washes: list[SprayPassMsg] | None = Field(
        default=None, description="the spray passes themselves, only when the request asked (SimStateRequest.washes)"
    )
    stamp: str = Field(default_factory=now_iso)


class SprayPassMsg(BaseModel):
    """One pass of the washing jet over the bin, in the **bin** frame (twin ground truth).

    As :class:`cellctl.sim.ground_truth.SprayPass`: the spot's path on the surface and the
    jet's direction at each spot.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    spots: list[tuple[FiniteFloat, FiniteFloat, FiniteFloat]] = Field(min_length=1, max_length=5000)
    axes: list[tuple[FiniteFloat, FiniteFloat, FiniteFloat]] = Field(min_length=1, max_length=5000)
    radius: FiniteFloat = Field(gt=0, le=1)
    cos_incidence: FiniteFloat = Field(ge=0, le=1)
    removal: FiniteFloat = Field(gt=0, le=1)

    @model_validator(mode="after")
    def _paired(self) -> SprayPassMsg:
        if len(self.spots) != len(self.axes):
            raise ValueError(f"a spray pass has {len(self.spots)} spots but {len(self.axes)} axes; expected one each")
        return self


# --- washing (robot op ``wash``) ---------------------------------------------------------------


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


# --- camera ---------------------------------------------------------------------------------


class Intrinsics(BaseModel):
    """Pinhole intrinsics in pixels, OpenCV distortion coefficients."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    width: int = Field(gt=0, le=65535)
    height: int = Field(gt=0, le=65535)
    fx: FiniteFloat = Field(gt=0)
    fy: FiniteFloat = Field(gt=0)
    cx: FiniteFloat
    cy: FiniteFloat
    dist: list[FiniteFloat] = Field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0, 0.0], max_length=14)

    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


class CaptureRequest(WireMessage):
    type: Literal["cellctl/CaptureRequest"] = "cellctl/CaptureRequest"
    v: Literal[1] = 1
    format: Literal["png", "jpeg"] = "png"


class CaptureReply(WireMessage):
    """Metadata of a captured image; the encoded image is the reply payload."""

    type: Literal["cellctl/CaptureReply"] = "cellctl/CaptureReply"
    v: Literal[1] = 1
    format: Literal["png", "jpeg"]
    intrinsics: Intrinsics
    camera_pose: PoseMsg | None = None
    stamp: str = Field(default_factory=now_iso)


# --- classifier -----------------------------------------------------------------------------


class ClassifyReference(BaseModel):
    """The stored reference a classify request asks the view to be compared with (issue 34).

    Poses are in the bin frame (``frame_id 'bin'``): each camera relative to the bin pose measured
    in its own cycle, so a bin parked elsewhere moves neither. The plane is the viewed wall in the
    reference camera's frame (from the bin mesh; the set stores no depth).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    image: str = Field(max_length=4096, description="the reference image's path on the worker's host")
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$", description="as the set's manifest records it")
    version: int = Field(ge=1, description="the reference set's version")
    reference_pose: PoseMsg = Field(description="the reference camera in the bin frame")
    view_pose: PoseMsg = Field(description="this view's camera in the bin frame")
    intrinsics: Intrinsics = Field(description="of the reference image (the same camera takes the view)")
    plane_normal: tuple[FiniteFloat, FiniteFloat, FiniteFloat]
    plane_distance: FiniteFloat = Field(description="m, in the reference camera's optical frame")


class ClassifyRequest(WireMessage):
    """Metadata of a classify request; the encoded image is the query payload."""

    type: Literal["cellctl/ClassifyRequest"] = "cellctl/ClassifyRequest"
    v: Literal[1] = 1
    surface: Surface
    format: Literal["png", "jpeg"] = "png"
    reference: ClassifyReference | None = Field(
        default=None, description="compare with this commissioned reference (None: the detector alone)"
    )


class ClassifyReply(WireMessage):
    type: Literal["cellctl/ClassifyReply"] = "cellctl/ClassifyReply"
    v: Literal[1] = 1
    label: Literal["clean", "dirty"]
    p_dirty: FiniteFloat = Field(ge=0.0, le=1.0)
    uncertain: bool = False
    model_id: str = Field(max_length=256)
    p_supervised: FiniteFloat | None = Field(default=None, ge=0.0, le=1.0, description="supervised part alone")
    anomaly_z: FiniteFloat | None = Field(default=None, description="clean-only part: largest patch distance, clean-σ")
    heatmap: str | None = Field(
        default=None, max_length=8192, description="per-patch p_dirty, base64 of uint8 p·255, row-major heat_grid²"
    )
    heat_grid: int | None = Field(default=None, ge=1, le=64)
    decided_by: Literal["reference", "detector", "model"] | None = Field(
        default=None,
        description="reference: the detector fused with the change map against the stored reference; detector: "
        "the detector alone; model: the whole-image model",
    )
    reference_reason: ReferenceReason | None = Field(
        default=None, description="a request with a reference: aligned, or why the detector decided alone"
    )


class ClassifierModelsRequest(WireMessage):
    """Ask the classifier worker which models it serves (``cell/<id>/classifier/models``)."""

    type: Literal["cellctl/ClassifierModelsRequest"] = "cellctl/ClassifierModelsRequest"
    v: Literal[1] = 1


class ClassifierModel(BaseModel):
    """One surface's model as the worker loaded it at start."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    model_id: str = Field(max_length=256)
    kind: Literal["detector", "enrolled", "supervised"] = Field(
        description="detector: the shipped <surface>.detect.pt; enrolled: classifier.detector_files; "
        "supervised: the whole-image model"
    )
    path: str = Field(max_length=4096)
    threshold: FiniteFloat = Field(ge=0.0, le=1.0)
    enrolled_on: dict[str, Any] | None = Field(
        default=None, description="enrolled: the card's source (folder, sha256, images) and base model id"
    )
    runtime: dict[str, Any] | None = Field(
        default=None,
        description="detectors: what runs the networks — onnx (export file, its sha256, intra-op threads) or torch",
    )


class ClassifierModels(WireMessage):
    """The classifier worker's models per surface, and those it could not load (why)."""

    type: Literal["cellctl/ClassifierModels"] = "cellctl/ClassifierModels"
    v: Literal[1] = 1
    decision: Literal["auto", "detector", "supervised"]
    models: dict[Surface, ClassifierModel] = Field(default_factory=dict)
    problems: dict[str, str] = Field(default_factory=dict)


# --- planner --------------------------------------------------------------------------------


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


# --- planner pool (compute host; docs/deploy/README.md) -----------------------------------


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


MESSAGE_TYPES: dict[str, type[WireMessage]] = {
    m.model_fields["type"].default: m
    for m in (
        Command,
        StartParams,
        Ack,
        Status,
        Event,
        FaultReport,
        CycleResult,
        ErrorReply,
        JointState,
        ApproachRequest,
        ApproachReply,
        MoveRequest,
        MoveReply,
        RobotStateRequest,
        RobotState,
        RobotMaintenanceRequest,
        RobotMaintenanceReply,
        StopRequest,
        SimStateRequest,
        SimScenarioRequest,
        SimState,
        WashRequest,
        WashReply,
        WashPlanRequest,
        WashPlanReply,
        CaptureRequest,
        CaptureReply,
        ClassifyRequest,
        ClassifyReply,
        ClassifierModelsRequest,
        ClassifierModels,
        PlanJobRequest,
        PlanJobReply,
        PlanJobProgress,
        PlanJobQuery,
        PlanLookupRequest,
        PlanLookupReply,
        PoolClaim,
        PoolAssignment,
        PoolDone,
        PoolStatsRequest,
        PoolStats,
        EnrollRequest,
        EnrollReply,
    )
}
"""Registry used by the codec: ``"cellctl/<Name>"`` → model class."""
