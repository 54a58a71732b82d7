"""The HMI's Zenoh link to the cell: last Status, events, alarms, results, and commands by query.

A plain client of the wire contract (like any PLC) through the one :class:`~cellctl.bus.plc_client.CellLink`:
it subscribes to ``status``, ``events`` and ``result``, and sends each Command as a query on ``cmd`` so the
Ack comes back as its reply. Callbacks only decode and store under a lock (they never block). The link's
thread opens the session, and opens it again when the daemon has been silent for ``reopen_s``, so an HMI
started before the daemon, or one whose daemon restarted, recovers by itself.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

from cellctl.bus.codec import decode_as
from cellctl.bus.plc_client import CellLink, RequestIds
from cellctl.config import CellConfig
from cellctl.errors import CellError
from cellctl.messages import Ack, Command, CycleResult, Event, Status, now_iso

__all__ = ["Alarm", "CellView", "LoggedEvent"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

ALARM_LEVELS = ("warning", "error", "fatal")
"""Event levels that raise an acknowledgeable alarm (ISA-18.2: an abnormal condition needing a response)."""


@dataclass
class LoggedEvent:
    seq: int
    level: str
    text: str
    cycle_id: str | None
    stamp: str
    source: str = "cell"

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class Alarm:
    id: int
    level: str
    text: str
    cycle_id: str | None
    stamp: str
    acked_by: str | None = None
    acked_at: str | None = None
    key: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if k != "key"}


def _decode(model: type, payload: bytes) -> Any:
    """The payload as ``model``, or None (logged) if it does not decode: a bad message is dropped, never raised."""
    try:
        return decode_as(model, payload)
    except CellError as err:
        log.warning("undecodable %s ignored: %s", model.__name__, err)
        return None


class CellView:
    """Everything the HMI knows about the cell from the bus (through the one :class:`CellLink`); thread-safe.

    Args:
        cfg: the cell config (endpoints, cell id, principal on a secured bus).
        stale_s: a Status older than this makes the cell "unreachable".
        events_kept: events remembered (newest first on the page).
        reopen_s: silent this long (and never answering a status query) → reopen the session.
    """

    def __init__(self, cfg: CellConfig, stale_s: float = 3.0, events_kept: int = 500, reopen_s: float = 10.0) -> None:
        self.cfg = cfg
        self.cell = cfg.cell_id
        self.stale_s = stale_s
        self.reopen_s = reopen_s
        self._lock = threading.Lock()
        self._status: Status | None = None
        self._status_at = 0.0
        self._open_error: str | None = "not connected yet"
        self._events: deque[LoggedEvent] = deque(maxlen=events_kept)
        self._alarms: dict[int, Alarm] = {}
        self._seq = itertools.count(1)
        self._ids = RequestIds("hmi", token=lambda: time.strftime("%Y%m%dT%H%M%S"), sep=":")
        self.last_result: CycleResult | None = None
        self.version = 0
        """Bumped on every change the pages show (server-sent events poll it)."""
        self.bus = CellLink(
            cfg, [self.cell], self._sink, reopen_s=reopen_s, down_reason=self._down_reason, thread_name="hmi-link"
        )
        self.bus.start()

    # --- the session ------------------------------------------------------------------------

    def _down_reason(self, err: CellError) -> str:
        # The page gets the endpoints and the hint, not Zenoh's text (it names source files);
        # the log keeps the whole message.
        hint = str(err).rsplit(" (", 1)[-1].rstrip(")") if str(err).endswith(")") else "is the daemon running?"
        return f"no daemon reachable at {', '.join(self.cfg.bus.connect)} ({hint}); retrying"

    def _sink(self, kind: str, cell: str, data: Any) -> None:
        if kind == "link":
            with self._lock:
                changed = self._open_error != data
                self._open_error = data
                if changed or data is None:
                    self.version += 1
        elif kind == "status":
            self._on_status(data)
        elif kind == "event":
            self._on_event(data)
        elif kind == "result":
            self._on_result(data)

    def add_subscriber(self, key: str, callback: Any) -> None:
        """Also subscribe ``callback`` to ``key`` (now, and on every reconnect); it must not block."""
        self.bus.add_subscriber(key, callback)

    def close(self) -> None:
        self.bus.close()

    # --- callbacks (Zenoh threads: decode, store, return) ------------------------------------

    def _on_status(self, payload: bytes) -> None:
        st = _decode(Status, payload)
        if st is None:
            return
        with self._lock:
            prev = self._status
            self._status, self._status_at = st, time.monotonic()
            if prev is None or prev.model_dump(exclude={"stamp"}) != st.model_dump(exclude={"stamp"}):
                self.version += 1
                if st.last_error and (prev is None or prev.last_error != st.last_error):
                    self._alarm_locked("error", f"{st.state}: {st.last_error}", st.cycle_id, now_iso(), st.last_error)

    def _on_event(self, payload: bytes) -> None:
        ev = _decode(Event, payload)
        if ev is None:
            return
        with self._lock:
            self._events.append(LoggedEvent(next(self._seq), ev.level, ev.text, ev.cycle_id, ev.stamp))
            if ev.level in ALARM_LEVELS:
                self._alarm_locked(ev.level, ev.text, ev.cycle_id, ev.stamp)
            self.version += 1

    def _on_result(self, payload: bytes) -> None:
        res = _decode(CycleResult, payload)
        if res is None:
            return
        with self._lock:
            self.last_result = res
            self.version += 1

    def _alarm_locked(self, level: str, text: str, cycle_id: str | None, stamp: str, key: str | None = None) -> None:
        # One fault, one alarm: the error event and the Status's last_error usually say the same thing.
        # ("scanning failed: X", then last_error "X" in Aborting): same cycle, one text inside the other.
        key = key or text
        for a in self._alarms.values():
            if a.cycle_id == cycle_id and a.acked_by is None and (key in a.key or a.key in key):
                return
        a = Alarm(next(self._seq), level, text, cycle_id, stamp, key=key)
        self._alarms[a.id] = a
        if len(self._alarms) > 200:  # keep the newest; acknowledged ones go first
            acked = [k for k, v in self._alarms.items() if v.acked_by]
            for k in (acked or list(self._alarms))[: len(self._alarms) - 200]:
                del self._alarms[k]

    # --- what the pages read -----------------------------------------------------------------

    def snapshot(self) -> dict[str, Any]:
        """The Status as JSON plus ``reachable`` / ``age_s`` / ``error`` (never raises)."""
        with self._lock:
            st, at, err = self._status, self._status_at, self._open_error
        age = time.monotonic() - at if st is not None else None
        reachable = st is not None and age is not None and age <= self.stale_s and self.bus.connected
        out: dict[str, Any] = {"reachable": reachable, "age_s": None if age is None else round(age, 3)}
        if not reachable:
            silent = "yet" if age is None else f"for {age:.0f} s"
            out["error"] = err or f"no Status from cell {self.cell!r} {silent}"
        out["status"] = st.model_dump(mode="json") if st is not None else None
        return out

    def events(self, limit: int = 200) -> list[dict[str, Any]]:
        with self._lock:
            return [e.as_dict() for e in list(self._events)[-limit:]][::-1]

    def alarms(self) -> list[dict[str, Any]]:
        with self._lock:
            return [a.as_dict() for a in sorted(self._alarms.values(), key=lambda a: -a.id)]

    def ack_alarm(self, alarm_id: int, user: str) -> Alarm | None:
        """Mark an alarm acknowledged by ``user``; None if there is no such alarm."""
        with self._lock:
            a = self._alarms.get(alarm_id)
            if a is None:
                return None
            if a.acked_by is None:
                a.acked_by, a.acked_at = user, now_iso()
                self._events.append(
                    LoggedEvent(
                        next(self._seq),
                        "info",
                        f"alarm {a.id} acknowledged: {a.text}",
                        a.cycle_id,
                        a.acked_at,
                        source=f"hmi:{user}",
                    )  # fmt: skip
                )
                self.version += 1
            return a

    def note(self, level: str, text: str, source: str) -> None:
        """An HMI-side entry in the event list (commands sent, logins)."""
        with self._lock:
            self._events.append(LoggedEvent(next(self._seq), level, text, None, now_iso(), source))
            self.version += 1

    # --- commands ----------------------------------------------------------------------------

    def send(self, cmd: Command, timeout: float) -> Ack:
        """Send ``cmd`` as a query on ``cmd`` and return the daemon's Ack.

        Raises:
            WorkerUnavailable: no session, or nobody serves the cmd key (daemon down).
            WorkerTimeout: the daemon did not answer in ``timeout`` s.
        """
        return self.bus.send(self.cell, cmd, timeout)

    def next_request_id(self, user: str) -> str:
        return self._ids.next(f"hmi:{user}")
