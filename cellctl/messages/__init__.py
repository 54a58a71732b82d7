"""Every wire message of cellctl as a typed, versioned model (wire contract v1).

Control payloads are JSON objects with ``"type"`` (``"cellctl/<Name>"``) and ``"v"``.
Images travel as encoded bytes (PNG/JPEG) in the payload, with their message (e.g.
:class:`CaptureReply`) as a JSON attachment. ``cellctl schema`` prints the JSON Schemas.

Add a message: subclass :class:`WireMessage` in the module of its concept, give it
``type: Literal["cellctl/Name"]`` and ``v: Literal[1]``, list it in :data:`MESSAGE_TYPES`
(:mod:`.registry`) and here. Changing a field of an existing message is a contract change:
bump ``v`` and keep decoding the old version.

Modules, one concept each (``from cellctl.messages import X`` is the way in):

- :mod:`.base`: the envelope :class:`WireMessage`, :class:`PoseMsg`, joints, the stamp, :class:`ErrorReply`;
- :mod:`.command`: the PackML command topic (:class:`Command`, :class:`StartParams`, :class:`Ack`);
- :mod:`.status`: :class:`Status` with its :class:`Admin` counters, :class:`Event`, :class:`FaultReport`;
- :mod:`.cycle`: :class:`CycleResult` and its per-viewpoint, per-station and commissioning records;
- :mod:`.robot`, :mod:`.camera`, :mod:`.classifier`, :mod:`.planner` (with the planner pool): each worker's ops;
- :mod:`.washing`: the wash ops and the wash-and-verify result; :mod:`.sim`: the twin's scenario and ground truth;
- :mod:`.registry`: :data:`MESSAGE_TYPES`, ``"cellctl/<Name>"`` → model class, what the codec decodes by.
"""

from cellctl.messages.base import ROBOT_JOINTS, WIRE_VERSION, ErrorReply, Joints, PoseMsg, WireMessage, now_iso
from cellctl.messages.camera import CaptureReply, CaptureRequest, Intrinsics
from cellctl.messages.classifier import (
    ClassifierModel,
    ClassifierModels,
    ClassifierModelsRequest,
    ClassifyReference,
    ClassifyReply,
    ClassifyRequest,
    EnrollReply,
    EnrollRequest,
    ReferenceReason,
)
from cellctl.messages.command import (
    MAX_REQUEST_ID_CHARS,
    MAX_USER_CHARS,
    START_MODES,
    START_PARAM_NAMES,
    Ack,
    Command,
    CommandName,
    PackMLCommand,
    StartMode,
    StartParams,
    UnitMode,
    UnitModeName,
)
from cellctl.messages.cycle import (
    BinInfo,
    CommissionResult,
    CycleOutcome,
    CycleResult,
    DecisionPath,
    StationResult,
    ViewpointResult,
)
from cellctl.messages.planner import (
    PlanJobProgress,
    PlanJobQuery,
    PlanJobReply,
    PlanJobRequest,
    PlanLookupReply,
    PlanLookupRequest,
    PlannedViewpoint,
    PoolAssignment,
    PoolClaim,
    PoolDone,
    PoolStats,
    PoolStatsRequest,
    StationInfo,
)
from cellctl.messages.registry import MESSAGE_TYPES
from cellctl.messages.robot import (
    ApproachReply,
    ApproachRequest,
    JointState,
    MoveReply,
    MoveRequest,
    RobotMaintenanceReply,
    RobotMaintenanceRequest,
    RobotState,
    RobotStateRequest,
    StopRequest,
)
from cellctl.messages.sim import SimScenarioRequest, SimState, SimStateRequest, SprayPassMsg
from cellctl.messages.status import (
    MAX_WARNINGS,
    Admin,
    Event,
    EventLevel,
    FaultCondition,
    FaultReport,
    LastCycle,
    Status,
)
from cellctl.messages.washing import (
    PlannedSweep,
    UnwashablePiece,
    WashPlanReply,
    WashPlanRequest,
    WashReply,
    WashRequest,
    WashResult,
    WashRound,
    WashSweep,
)

__all__ = [
    "Ack",
    "Admin",
    "ApproachReply",
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
    "CommissionResult",
    "CycleOutcome",
    "CycleResult",
    "DecisionPath",
    "EnrollReply",
    "EnrollRequest",
    "ErrorReply",
    "Event",
    "EventLevel",
    "FaultCondition",
    "FaultReport",
    "Intrinsics",
    "JointState",
    "Joints",
    "LastCycle",
    "MAX_REQUEST_ID_CHARS",
    "MAX_USER_CHARS",
    "MAX_WARNINGS",
    "MESSAGE_TYPES",
    "MoveReply",
    "MoveRequest",
    "PackMLCommand",
    "PlanJobProgress",
    "PlanJobQuery",
    "PlanJobReply",
    "PlanJobRequest",
    "PlanLookupReply",
    "PlanLookupRequest",
    "PlannedSweep",
    "PlannedViewpoint",
    "PoolAssignment",
    "PoolClaim",
    "PoolDone",
    "PoolStats",
    "PoolStatsRequest",
    "PoseMsg",
    "ROBOT_JOINTS",
    "ReferenceReason",
    "RobotMaintenanceReply",
    "RobotMaintenanceRequest",
    "RobotState",
    "RobotStateRequest",
    "START_MODES",
    "START_PARAM_NAMES",
    "SimScenarioRequest",
    "SimState",
    "SimStateRequest",
    "SprayPassMsg",
    "StartMode",
    "StartParams",
    "StationInfo",
    "StationResult",
    "Status",
    "StopRequest",
    "UnitMode",
    "UnitModeName",
    "UnwashablePiece",
    "ViewpointResult",
    "WIRE_VERSION",
    "WashPlanReply",
    "WashPlanRequest",
    "WashReply",
    "WashRequest",
    "WashResult",
    "WashRound",
    "WashSweep",
    "WireMessage",
    "now_iso",
]
