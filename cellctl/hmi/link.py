"""The HMI's Zenoh link to the cell: last Status, events, alarms, results, and commands by query.

A plain client of the wire contract (like any PLC): it subscribes to ``status``, ``events`` and
``result``, and sends each Command as a query on ``cmd`` so the Ack comes back as its reply.
Zenoh callbacks only decode and store under a lock (they never block). A background thread
opens the session, and opens it again when the daemon has been silent for a while, so an HMI
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

from cellctl.bus import keys
from cellctl.bus.codec import decode_as, encode
from cellctl.config import CellConfig
from cellctl.errors import CellError, WorkerTimeout, WorkerUnavailable
from cellctl.messages import Ack, Command, CycleResult, Event, Status, now_iso

__all__ = ["Alarm", "CellLink", "LoggedEvent"]

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


def _decode(model: type, sample: Any) -> Any:
    """The sample as ``model``, or None (logged) if it does not decode: a bad message is dropped, never raised."""
    try:
        return decode_as(model, sample.payload.to_bytes())
    except CellError as err:
        log.warning("undecodable %s ignored: %s", model.__name__, err)
        return None


class CellLink:
    """Everything the HMI knows about the cell from the bus; thread-safe.

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
        self._session: Any = None
        self._subs: list[Any] = []
        self._status: Status | None = None
        self._status_at = 0.0
        self._open_error: str | None = "not connected yet"
        self._events: deque[LoggedEvent] = deque(maxlen=events_kept)
        self._alarms: dict[int, Alarm] = {}
        self._seq = itertools.count(1)
        self._req = itertools.count(1)
        self.last_result: CycleResult | None = None
        self.version = 0
        """Bumped on every change the pages show (server-sent events poll it)."""
        self._extra: list[tuple[str, Any]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._keep_open, name="hmi-link", daemon=True)
        self._thread.start()

    # --- the session ------------------------------------------------------------------------

    def _keep_open(self) -> None:
        while not self._stop.is_set():
            if self._session is None:
                self._open()
            elif time.monotonic() - self._status_at > self.reopen_s:
                self._probe()
            self._stop.wait(1.0)

    def _open(self) -> None:
        from cellctl.bus.session import open_session

        try:
            s = open_session(self.cfg, "client")
        except CellError as err:
            # The page gets the endpoints and the hint, not Zenoh's text (it names source files);
            # the log keeps the whole message.
            hint = str(err).rsplit(" (", 1)[-1].rstrip(")") if str(err).endswith(")") else "is the daemon running?"
            short = f"no daemon reachable at {', '.join(self.cfg.bus.connect)} ({hint}); retrying"
            with self._lock:
                if self._open_error != short:
                    log.warning("HMI: %s (retrying every second)", err)
                self._open_error = short
            return
        c = self.cell
        subs = [
            s.declare_subscriber(keys.status(c), self._on_status),
            s.declare_subscriber(keys.events(c), self._on_event),
            s.declare_subscriber(keys.result(c), self._on_result),
            *(s.declare_subscriber(key, cb) for key, cb in list(self._extra)),
        ]
        with self._lock:
            self._session, self._subs, self._open_error = s, subs, None
            self.version += 1
        self._probe()

    def add_subscriber(self, key: str, callback: Any) -> None:
        """Also subscribe ``callback`` to ``key`` (now, and on every reconnect); it must not block."""
        with self._lock:
            self._extra.append((key, callback))
            s = self._session
            if s is not None:
                self._subs.append(s.declare_subscriber(key, callback))

    def _probe(self) -> None:
        """Ask for the Status; after a long silence with no answer, start over with a new session."""
        s = self._session
        try:
            replies = list(s.get(keys.status(self.cell), timeout=1.0))
            if replies and replies[0].ok is not None:
                self._on_status(replies[0].ok)
                return
        except Exception as err:  # a closed or broken session raises zenoh's own error
            log.debug("status probe failed: %s", err)
        if time.monotonic() - self._status_at > self.reopen_s:
            self._close_session()

    def _close_session(self) -> None:
        with self._lock:
            s, subs = self._session, self._subs
            self._session, self._subs = None, []
            self._open_error = "the daemon stopped answering; reconnecting"
            self.version += 1
        for sub in subs:
            try:
                sub.undeclare()
            except Exception:  # the session may be gone already
                pass
        if s is not None:
            try:
                s.close()
            except Exception:
                pass

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._close_session()

    # --- callbacks (Zenoh threads: decode, store, return) ------------------------------------

    def _on_status(self, sample: Any) -> None:
        st = _decode(Status, sample)
        if st is None:
            return
        with self._lock:
            prev = self._status
            self._status, self._status_at = st, time.monotonic()
            if prev is None or prev.model_dump(exclude={"stamp"}) != st.model_dump(exclude={"stamp"}):
                self.version += 1
                if st.last_error and (prev is None or prev.last_error != st.last_error):
                    self._alarm_locked("error", f"{st.state}: {st.last_error}", st.cycle_id, now_iso(), st.last_error)

    def _on_event(self, sample: Any) -> None:
        ev = _decode(Event, sample)
        if ev is None:
            return
        with self._lock:
            self._events.append(LoggedEvent(next(self._seq), ev.level, ev.text, ev.cycle_id, ev.stamp))
            if ev.level in ALARM_LEVELS:
                self._alarm_locked(ev.level, ev.text, ev.cycle_id, ev.stamp)
            self.version += 1

    def _on_result(self, sample: Any) -> None:
        res = _decode(CycleResult, sample)
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
        reachable = st is not None and age is not None and age <= self.stale_s and self._session is not None
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
        s = self._session
        if s is None:
            raise WorkerUnavailable(f"cell unreachable: {self._open_error}")
        try:
            replies = list(s.get(keys.cmd(self.cell), payload=encode(cmd), timeout=timeout))
        except Exception as err:  # a session closed under us
            raise WorkerUnavailable(f"cell unreachable: {err}") from err
        if not replies:
            from cellctl.bus.security import acl_hint

            k = keys.cmd(self.cell)
            raise WorkerUnavailable(f"cell unreachable: no daemon serves {k!r}" + acl_hint(self.cfg.bus, k))
        if replies[0].ok is None:
            raise WorkerTimeout(f"the daemon did not answer {cmd.request_id!r} within {timeout:g} s")
        return decode_as(Ack, replies[0].ok.payload.to_bytes())

    def next_request_id(self, user: str) -> str:
        return f"hmi:{user}:{time.strftime('%Y%m%dT%H%M%S')}-{next(self._req)}"
