"""What the supervisor says on the bus: Acks, Status, CycleResults and Events of one cell.

Acks, results and events are declared with ``CongestionControl.BLOCK`` and ``RELIABLE``: the
default (``DROP``) lets a full transmission queue drop a message, and a burst of put commands
answered by a burst of Acks to a busy client is exactly that case. Status stays ``DROP``: it is
a latest-value topic re-published every second and readable by query.
"""

from __future__ import annotations

import logging
from typing import Any

import zenoh

from cellctl.bus import keys
from cellctl.bus.codec import encode
from cellctl.messages import Ack, Admin, CycleResult, Event, EventLevel, Status, UnitMode
from cellctl.supervisor.definition import PackMLState
from cellctl.supervisor.events import Query
from cellctl.supervisor.recorder import Recorder

__all__ = ["Outbox", "make_status", "reply"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

_MUST_ARRIVE = {"congestion_control": zenoh.CongestionControl.BLOCK, "reliability": zenoh.Reliability.RELIABLE}


def reply(query: Query, payload: bytes) -> None:
    """Answer a query once and finalise it (the querier's get returns at once)."""
    try:
        query.reply(query.key_expr, payload, congestion_control=zenoh.CongestionControl.BLOCK)
    finally:
        query.drop()


def make_status(
    cell: str,
    state: str,
    *,
    cycle_id: str | None,
    available: list[str],
    last_error: str | None,
    workers: dict[str, bool],
    mode: UnitMode,
    admin: Admin,
) -> Status:
    """The Status of a cell in ``state`` (full name, e.g. ``Execute.scanning``)."""
    top, _, step = state.partition(".")
    return Status(
        cell=cell,
        state=top,
        state_code=PackMLState[top].value,
        step=step or None,
        cycle_id=cycle_id,
        available_commands=available,
        unit_mode=mode.name,
        unit_mode_code=mode.value,
        last_error=last_error,
        workers=workers,
        admin=admin,
    )


class Outbox:
    """The cell's publishers; without :meth:`declare` (no session) every send is a no-op."""

    def __init__(self, session: Any, cell_id: str) -> None:
        self.session = session
        self.cell_id = cell_id
        self._pub: dict[str, Any] = {}

    def declare(self) -> None:
        s, c = self.session, self.cell_id
        self._pub = {
            "ack": s.declare_publisher(keys.cmd_ack(c), **_MUST_ARRIVE),
            "status": s.declare_publisher(keys.status(c)),
            "result": s.declare_publisher(keys.result(c), **_MUST_ARRIVE),
            "events": s.declare_publisher(keys.events(c), **_MUST_ARRIVE),
        }

    def undeclare(self) -> None:
        for p in self._pub.values():
            try:
                p.undeclare()
            except Exception:  # already closed with the session
                pass
        self._pub.clear()

    def _put(self, name: str, payload: bytes) -> None:
        pub = self._pub.get(name)
        if pub is not None:
            pub.put(payload)

    def ack(self, ack: Ack, query: Query | None) -> None:
        """The Ack as the query's reply, or on ``cmd/ack`` for a put."""
        if query is not None:
            reply(query, encode(ack))
        else:
            self._put("ack", encode(ack))
        if not ack.accepted:
            log.info("command rejected: %s", ack.reason)

    def status(self, st: Status) -> None:
        self._put("status", encode(st))

    def result(self, res: CycleResult) -> None:
        self._put("result", encode(res))

    def announce(self, level: str, text: str, cycle_id: str | None, record: Recorder | None) -> None:
        """An Event on ``events`` (and in the cycle's log when one is open), and in the log file."""
        ev = Event(level=level, text=text, cycle_id=cycle_id)  # type: ignore[arg-type]
        if record is not None:
            record.event(int(EventLevel[level]), text)
        self._put("events", encode(ev))
        log.info("[%s] %s", level, text)
