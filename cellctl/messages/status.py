"""What the cell reports: the PackML status with its Admin counters, events, and workers' fault reports."""

from __future__ import annotations

import enum
from typing import TYPE_CHECKING, Literal

from pydantic import BaseModel, ConfigDict, Field

from cellctl.messages.base import WireMessage, now_iso
from cellctl.messages.command import UnitModeName

if TYPE_CHECKING:
    from cellctl.messages.cycle import CycleResult


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
