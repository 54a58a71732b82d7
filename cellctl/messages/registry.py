"""The registry of wire message types the codec decodes by: ``"cellctl/<Name>"`` → model class."""

from __future__ import annotations

from cellctl.messages.base import ErrorReply, WireMessage
from cellctl.messages.camera import CaptureReply, CaptureRequest
from cellctl.messages.classifier import (
    ClassifierModels,
    ClassifierModelsRequest,
    ClassifyReply,
    ClassifyRequest,
    EnrollReply,
    EnrollRequest,
)
from cellctl.messages.command import Ack, Command, StartParams
from cellctl.messages.cycle import CycleResult
from cellctl.messages.planner import (
    PlanJobProgress,
    PlanJobQuery,
    PlanJobReply,
    PlanJobRequest,
    PlanLookupReply,
    PlanLookupRequest,
    PoolAssignment,
    PoolClaim,
    PoolDone,
    PoolStats,
    PoolStatsRequest,
)
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
from cellctl.messages.sim import SimScenarioRequest, SimState, SimStateRequest
from cellctl.messages.status import Event, FaultReport, Status
from cellctl.messages.washing import WashPlanReply, WashPlanRequest, WashReply, WashRequest

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
