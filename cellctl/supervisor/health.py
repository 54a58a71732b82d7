"""Worker health beside the roster: a worker's fault report joined to its token's loss.

A worker that faults reports why (:class:`~cellctl.messages.FaultReport`, or the first form: an error
Event ``"<role> fault: <text>"``) and withdraws its liveliness token. The report is a put and the loss
a liveliness undeclaration: Zenoh orders neither against the other, so either may come first.
:class:`WorkerHealth` joins them within :data:`FAULT_WINDOW_S` of its clock: a loss after a report is
stopped with the fault's words; a report after a loss emits :class:`FaultExplainsLoss`, which the
dispatcher applies wherever the loss's reason went (one :class:`StopReason` value, found by identity).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from cellctl.bus import keys
from cellctl.bus.codec import decode
from cellctl.errors import ProtocolError
from cellctl.messages import Event, FaultReport

__all__ = ["FAULT_WINDOW_S", "FaultExplainsLoss", "StopReason", "WorkerHealth"]

FAULT_WINDOW_S = 2.0
"""A worker's fault report and its token's loss belong together within this window (either order)."""


class StopReason(str):
    """Why a cycle stopped on a lost worker: the loss, or the worker's own fault once its report is in.

    A ``str`` (what the cycle, the Status's ``last_error`` and the Admin's ``stop_reason`` carry), and one
    value: the dispatcher finds where it went by identity, never by comparing text.
    """

    role: str
    state: str
    cycle_id: str | None
    fault: str | None

    def __new__(cls, role: str, state: str, cycle_id: str | None, fault: str | None = None) -> StopReason:
        text = (
            f"{role} worker lost (liveliness token gone) in {state}"
            if fault is None
            else f"{fault} ({role} worker unavailable in {state})"
        )
        self = super().__new__(cls, text)
        self.role, self.state, self.cycle_id, self.fault = role, state, cycle_id, fault
        return self

    def __reduce__(self) -> tuple[type[StopReason], tuple[str, str, str | None, str | None]]:
        return StopReason, (self.role, self.state, self.cycle_id, self.fault)  # copies and pickles keep the parts

    def explained(self, fault: str) -> StopReason:
        """The same loss, named by the worker's fault."""
        return StopReason(self.role, self.state, self.cycle_id, fault)


@dataclass(frozen=True)
class FaultExplainsLoss:
    """A fault report came after its worker's loss (within the window): ``before`` becomes ``after``."""

    before: StopReason
    after: StopReason


class WorkerHealth:
    """Fault reports and token losses per role, joined in time (dispatcher thread only).

    Args:
        clock: monotonic seconds (tests inject a fake one).
        on_report: called with each active typed report (the open cycle records it).
        window_s: how far apart a report and a loss may be and still be one fault.
    """

    def __init__(
        self,
        clock: Callable[[], float] = time.monotonic,
        on_report: Callable[[FaultReport], None] | None = None,
        window_s: float = FAULT_WINDOW_S,
    ) -> None:
        self.clock, self.on_report, self.window_s = clock, on_report, window_s
        self.faults: dict[str, tuple[float, str]] = {}
        """role -> (clock time, text) of its last fault report."""
        self.fault_reports: dict[str, FaultReport] = {}
        """role -> its last typed fault report (condition, robot mode, safety bits), while active."""
        self.lost: dict[str, tuple[float, StopReason]] = {}
        """role -> (clock time, reason) of its last token loss in a cycle, while no report explains it."""

    def loss(self, role: str, state: str, cycle_id: str | None) -> StopReason:
        """``role``'s token went in ``state``: the reason to stop with (its fault's words when reported in time)."""
        now = self.clock()
        fault = self.faults.get(role)
        if fault is not None and now - fault[0] <= self.window_s:
            return StopReason(role, state, cycle_id, fault[1])
        reason = StopReason(role, state, cycle_id)
        self.lost[role] = (now, reason)
        return reason

    def report(self, payload: bytes) -> FaultExplainsLoss | None:
        """Take one payload from a worker's fault key; the event when it explains a loss that came first."""
        found = self._fault_text(payload)
        if found is None:
            return None
        role, text = found
        now = self.clock()
        self.faults[role] = (now, text)
        lost = self.lost.pop(role, None)
        if lost is None or now - lost[0] > self.window_s:
            return None
        return FaultExplainsLoss(lost[1], lost[1].explained(text))

    def _fault_text(self, payload: bytes) -> tuple[str, str] | None:
        """(role, text) of an active fault report; a cleared report forgets the role's fault."""
        try:
            msg = decode(payload)
        except ProtocolError:
            return None
        if isinstance(msg, FaultReport):
            if msg.role not in keys.ROLES:
                return None
            if not msg.active:  # cleared by an operator: no reason for a later loss
                self.fault_reports.pop(msg.role, None)
                self.faults.pop(msg.role, None)
                return None
            self.fault_reports[msg.role] = msg
            if self.on_report is not None:
                self.on_report(msg)
            return msg.role, msg.text
        if isinstance(msg, Event):
            role, sep, _ = msg.text.partition(" fault: ")
            if msg.level == "error" and sep and role in keys.ROLES:
                return role, msg.text
        return None
