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
from cellctl.bus.codec import MAX_PAYLOAD_BYTES, encode
from cellctl.messages import Ack, Admin, CycleResult, Event, EventLevel, Status, UnitMode
from cellctl.supervisor.definition import PackMLState
from cellctl.supervisor.events import Query
from cellctl.supervisor.recorder import Recorder

__all__ = ["Outbox", "fit_to_wire", "make_status", "reply"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

_MUST_ARRIVE = {"congestion_control": zenoh.CongestionControl.BLOCK, "reliability": zenoh.Reliability.RELIABLE}


def reply(query: Query, payload: bytes) -> None:
    """Answer a query once and finalise it (the querier's get returns at once)."""
    try:
        query.reply(query.key_expr, payload, congestion_control=zenoh.CongestionControl.BLOCK)
    finally:
        query.drop()


def fit_to_wire(res: CycleResult, limit: int = MAX_PAYLOAD_BYTES) -> bytes:
    """The result's bytes for the bus, within the size every subscriber accepts.

    A whole-bin wash cycle can carry a few hundred views with heat maps, past ``limit``; every subscriber
    (`PlcClient`, the gateway, the HMI) refuses such a payload, so the PLC would wait out its cycle timeout for a
    result that came. What is left out is what the cycle's MCAP holds anyway, least telling first: the views' heat
    maps and model ids (``classifier_models`` names the models), then the clean views, then every view.
    ``viewpoints_omitted`` says how many views are missing or cut.
    """
    data = encode(res)
    if len(data) <= limit:
        return data
    views = res.viewpoints
    trimmed = [
        v.model_copy(update={"heatmap": None, "model_id": None}) if v.heatmap is not None or v.model_id else v
        for v in views
    ]
    telling = [v for v in trimmed if v.label != "clean" or v.uncertain or v.error is not None]
    untouched = {id(v) for v in views}
    for kept in (trimmed, telling, []):
        omitted = len(views) - sum(1 for v in kept if id(v) in untouched)
        data = encode(res.model_copy(update={"viewpoints": kept, "viewpoints_omitted": omitted}))
        if len(data) <= limit:
            log.warning(
                "cycle %s: result cut to %d bytes for the wire (%d of %d views left out or without heat map; "
                "the MCAP has them)",
                res.cycle_id,
                len(data),
                omitted,
                len(views),
            )
            return data
    log.error("cycle %s: result is %d bytes without any view, over the %d-byte limit", res.cycle_id, len(data), limit)
    return data


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
        unit_mode=mode.wire_name,
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
        self._put("result", fit_to_wire(res))

    def announce(self, level: str, text: str, cycle_id: str | None, record: Recorder | None) -> None:
        """An Event on ``events`` (and in the cycle's log when one is open), and in the log file."""
        ev = Event(level=level, text=text, cycle_id=cycle_id)  # type: ignore[arg-type]
        if record is not None:
            record.event(int(EventLevel[level]), text)
        self._put("events", encode(ev))
        log.info("[%s] %s", level, text)
