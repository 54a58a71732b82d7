"""The one client of the cell's PLC contract: commands by query, Status/CycleResult/Event by subscription.

Everything that drives or watches a cell the way a PLC would goes through :class:`CellLink` (the
OPC UA gateway, the HMI, ``cellctl demo``, the cycle, fault and soak benches), so the wire
behaviour (keys, request ids, stamps, the query that carries a Command and brings its Ack back) is
written once. Each caller's own needs are parameters: the gateway's several cells and liveliness,
the HMI's reopen-after-silence, the PLC tools' blocking waits (:class:`PlcClient`, on top).
"""

from __future__ import annotations

import itertools
import logging
import queue
import secrets
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

import zenoh

from cellctl.bus import keys
from cellctl.bus.codec import decode_as, encode
from cellctl.bus.security import acl_hint
from cellctl.bus.session import open_session
from cellctl.config import CellConfig
from cellctl.errors import CellError, ProtocolError, WorkerTimeout, WorkerUnavailable
from cellctl.messages import (
    Ack,
    Command,
    CommandName,
    CycleResult,
    Event,
    PlanJobProgress,
    Status,
    UnitModeName,
    now_iso,
)

__all__ = ["CellLink", "PlcClient", "RequestIds", "Sink"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

Sink = Callable[[str, str, Any], None]
"""``sink(kind, cell, data)``: kind ``status``/``result``/``event``/``progress`` (payload bytes), ``alive``
(bool), or ``link`` (cell ``""``, data: None when connected, else the reason). Called on Zenoh threads
and the link's thread: it must not block."""

SILENT_REASON = "the daemon stopped answering; reconnecting"


def _not_connected(err: CellError) -> str:
    return f"not connected to the cell bus: {err}"


class RequestIds:
    """The request ids one client sends: ``{prefix}{sep}{token}-{n}``.

    The supervisor refuses an id it already acted on (600 s window), so the token keeps ids unique
    across the client's restarts: by default a random per-process token (``plc-1a2b3c-7``); the HMI
    passes a wall-clock token and a per-user prefix (``hmi:alice:20260101T120000-7``).
    """

    def __init__(self, prefix: str, token: Callable[[], str] | None = None, sep: str = "-") -> None:
        boot = secrets.token_hex(3)
        self.prefix = prefix
        self.sep = sep
        self._token = token or (lambda: boot)
        self._seq = itertools.count(1)

    def next(self, prefix: str | None = None) -> str:
        """The next id (``prefix`` replaces the default one, e.g. to name the user)."""
        return f"{self.prefix if prefix is None else prefix}{self.sep}{self._token()}-{next(self._seq)}"


class CellLink:
    """A Zenoh client session of one or more cells' PLC contract.

    Args:
        cfg: the cell config (bus endpoints, security); the session is opened as ``cfg.bus.principal``.
        cells: the cell ids whose keys are subscribed (default: ``cfg.cell_id``).
        sink: receives every sample (see :data:`Sink`).
        reconnect_s: retry period while the router cannot be reached (background mode, :meth:`start`).
        reopen_s: None: the session, once open, is kept (Zenoh's client reconnects to a restarted router by
            itself). A number: silent this long (no Status, and no answer to a status query) → reopen it.
        events: subscribe to Events.
        progress: subscribe to planning-job progress.
        liveliness: subscribe to the supervisor's liveliness token (history included).
        down_reason: the ``link`` reason for a session that cannot be opened.
    """

    def __init__(
        self,
        cfg: CellConfig,
        cells: Iterable[str] | None = None,
        sink: Sink | None = None,
        *,
        reconnect_s: float = 1.0,
        reopen_s: float | None = None,
        events: bool = True,
        progress: bool = False,
        liveliness: bool = False,
        down_reason: Callable[[CellError], str] = _not_connected,
        thread_name: str = "cell-link",
    ) -> None:
        self.cfg = cfg
        self.cells = list(cells) if cells is not None else [cfg.cell_id]
        self._sink: Sink = sink or (lambda kind, cell, data: None)
        self._reconnect_s = reconnect_s
        self._reopen_s = reopen_s
        self._kinds = [("status", keys.status), ("result", keys.result)]
        if events:
            self._kinds.append(("event", keys.events))
        if progress:
            self._kinds.append(("progress", keys.planner_job_progress))
        self._liveliness = liveliness
        self._down_reason = down_reason
        self._lock = threading.Lock()
        self._session: Any = None
        self._handles: list[Any] = []
        self._extra: list[tuple[str, Any]] = []
        self._heard_at = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=thread_name, daemon=True)
        self.last_error: str | None = None

    # --- the session ------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._session is not None

    @property
    def session(self) -> Any:
        """The open Zenoh session, or None (for a tool's own extra queries)."""
        return self._session

    def connect(self) -> None:
        """Open the session now, in the caller's thread.

        Raises:
            CellError: the bus cannot be reached (``open_session``'s error), or a subscription is refused.
        """
        s = open_session(self.cfg, "client")
        try:
            self._declare(s)
        except Exception:
            s.close()
            raise
        with self._lock:
            self._session = s
        self.last_error = None

    def start(self) -> None:
        """Open (and keep open) the session in a background thread; ``link`` samples tell the sink how it goes."""
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            if self._session is None:
                if not self._open():
                    self._stop.wait(self._reconnect_s)
                    continue
                if self._reopen_s is not None:
                    self._probe()
            elif self._reopen_s is not None and time.monotonic() - self._heard_at > self._reopen_s:
                self._probe()
            self._stop.wait(None if self._reopen_s is None else 1.0)

    def _open(self) -> bool:
        try:
            session = open_session(self.cfg, "client")
        except CellError as err:
            if self.last_error != str(err):
                log.warning("bus not reachable (retrying every %.1f s): %s", self._reconnect_s, err)
            self.last_error = str(err)
            self._sink("link", "", self._down_reason(err))
            return False
        try:
            self._declare(session)
        except Exception as err:  # a refused declaration must not kill the link thread
            log.exception("cannot subscribe on the cell bus")
            self._sink("link", "", f"cannot subscribe on the cell bus: {err}")
            session.close()
            return False
        with self._lock:
            self._session = session
        self.last_error = None
        self._sink("link", "", None)
        log.info("connected to the cell bus %s as %r", self.cfg.bus.connect, self.cfg.bus.principal)
        return True

    def _declare(self, session: Any) -> None:
        handles: list[Any] = []
        for cell in self.cells:
            for kind, key in self._kinds:
                cb = self._on_status if kind == "status" else self._forward
                handles.append(session.declare_subscriber(key(cell), lambda s, k=kind, c=cell, f=cb: f(k, c, s)))
            if self._liveliness:
                handles.append(
                    session.liveliness().declare_subscriber(
                        keys.alive(cell, "supervisor"),
                        lambda s, c=cell: self._sink("alive", c, s.kind == zenoh.SampleKind.PUT),
                        history=True,
                    )
                )
        with self._lock:
            handles.extend(session.declare_subscriber(key, cb) for key, cb in self._extra)
            self._handles = handles

    def _forward(self, kind: str, cell: str, sample: Any) -> None:
        self._sink(kind, cell, sample.payload.to_bytes())

    def _on_status(self, kind: str, cell: str, sample: Any) -> None:
        self._heard_at = time.monotonic()
        self._sink(kind, cell, sample.payload.to_bytes())

    def add_subscriber(self, key: str, callback: Any) -> None:
        """Also subscribe ``callback`` to ``key`` (now, and on every reopen); it must not block."""
        with self._lock:
            self._extra.append((key, callback))
            s = self._session
            if s is not None:
                self._handles.append(s.declare_subscriber(key, callback))

    def _probe(self) -> None:
        """Ask each cell for its Status; after a long silence with no answer, close (the loop reopens)."""
        for cell in self.cells:
            payload = self.query_status(cell, timeout=1.0)
            if payload is not None:
                self._heard_at = time.monotonic()
                self._sink("status", cell, payload)
        if self._reopen_s is not None and time.monotonic() - self._heard_at > self._reopen_s:
            self._close_session()
            self._sink("link", "", SILENT_REASON)

    def _close_session(self) -> None:
        with self._lock:
            session, handles = self._session, self._handles
            self._session, self._handles = None, []
        for h in handles:
            try:
                h.undeclare()
            except Exception:  # the session may already be gone
                pass
        if session is not None:
            try:
                session.close()
            except Exception:  # closing a broken session raises zenoh's own error
                pass

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)
        self._close_session()

    # --- commands and queries ------------------------------------------------------------------

    def _unreachable(self) -> WorkerUnavailable:
        return WorkerUnavailable(f"not connected to the cell bus {self.cfg.bus.connect}: {self.last_error}")

    def send(self, cell: str, cmd: Command, timeout: float) -> Ack:
        """Send ``cmd`` to ``cell`` as a query on its ``cmd`` key and return the daemon's Ack.

        Raises:
            WorkerUnavailable: no session, or nobody serves the cmd key (daemon down).
            WorkerTimeout: the daemon did not answer in ``timeout`` s.
        """
        s = self._session
        if s is None:
            raise self._unreachable()
        key = keys.cmd(cell)
        try:
            replies = list(
                s.get(key, payload=encode(cmd), timeout=timeout, congestion_control=zenoh.CongestionControl.BLOCK)
            )
        except Exception as err:  # a session closed under us
            raise WorkerUnavailable(f"cell unreachable: {err}") from err
        if not replies:
            raise WorkerUnavailable(f"cell unreachable: no daemon serves {key!r}" + acl_hint(self.cfg.bus, key))
        if replies[0].ok is None:
            raise WorkerTimeout(f"the daemon did not answer {cmd.request_id!r} within {timeout:g} s")
        return decode_as(Ack, replies[0].ok.payload.to_bytes())

    def put(self, cell: str, cmd: Command, timeout: float) -> Ack:
        """Send ``cmd`` to ``cell`` by put (no reply channel) and return its Ack read from ``cmd/ack``.

        The path of a PLC that cannot query: the daemon answers every command on ``cmd/ack`` as well; the
        Ack is matched by ``cmd.request_id``.

        Raises:
            WorkerUnavailable: no session.
            WorkerTimeout: no Ack with the command's request id on ``cmd/ack`` within ``timeout`` s.
        """
        s = self._session
        if s is None:
            raise self._unreachable()
        # the callback only hands the bytes over: decoding there would raise on a malformed Ack inside
        # Zenoh's thread; here a malformed one is skipped like another command's Ack
        acks: queue.Queue[bytes] = queue.Queue()
        sub = s.declare_subscriber(keys.cmd_ack(cell), lambda smp: acks.put(smp.payload.to_bytes()))
        try:
            time.sleep(0.1)  # let the subscription reach the router before the put
            # BLOCK: the default (DROP) may drop a put at a full transmission queue, and nothing would answer
            s.put(keys.cmd(cell), encode(cmd), congestion_control=zenoh.CongestionControl.BLOCK)
            deadline = time.monotonic() + timeout
            while (left := deadline - time.monotonic()) > 0:
                try:
                    raw = acks.get(timeout=left)
                except queue.Empty:
                    break
                try:
                    ack = decode_as(Ack, raw)
                except ProtocolError:
                    continue
                if ack.request_id == cmd.request_id:
                    return ack
        finally:
            sub.undeclare()
        raise WorkerTimeout(
            f"no Ack on {keys.cmd_ack(cell)} within {timeout:g} s" + acl_hint(self.cfg.bus, keys.cmd(cell))
        )

    def send_async(self, cell: str, cmd: Command, timeout: float, done: Callable[[Ack | CellError], None]) -> None:
        """Send ``cmd`` to ``cell`` by query without blocking; ``done`` gets its Ack or the error.

        ``done`` runs once, on a Zenoh thread, when the query is finished (replies in or timed out):
        the caller's thread sends the query itself, with no hand-over to another thread first, which
        is on the path of every command's StateCurrent change (the gateway). The errors:
        WorkerUnavailable (not connected, or no daemon serves the key), WorkerTimeout (no answer
        within ``timeout``), ProtocolError (the reply is not an Ack).
        """
        session = self._session
        key = keys.cmd(cell)
        if session is None:
            done(self._unreachable())
            return
        first: list[Any] = []

        def on_reply(rep: Any) -> None:
            if not first:
                first.append(rep)

        def on_drop() -> None:
            if not first:
                done(WorkerUnavailable(f"no cellctl daemon serves {key!r} (daemon down?)"))
            elif first[0].ok is None:
                done(WorkerTimeout(f"the daemon did not answer {key!r} within {timeout:g} s"))
            else:
                try:
                    done(decode_as(Ack, first[0].ok.payload.to_bytes()))
                except ProtocolError as err:
                    done(ProtocolError(f"the daemon answered {key!r} with something other than an Ack: {err}"))

        # indirect=False: the two callbacks above only append and decode, so they run on Zenoh's thread
        handler = zenoh.handlers.Callback(on_reply, on_drop, indirect=False)
        session.get(key, handler, payload=encode(cmd), timeout=timeout)

    def query_status(self, cell: str, timeout: float = 2.0) -> bytes | None:
        """The cell's current Status payload by query, or None (not connected, no daemon)."""
        session = self._session
        if session is None:
            return None
        try:
            replies = list(session.get(keys.status(cell), timeout=timeout))
        except Exception:  # a closing session; the caller retries on the next tick
            return None
        if not replies or replies[0].ok is None:
            return None
        payload: bytes = replies[0].ok.payload.to_bytes()
        return payload


class PlcClient:
    """A PLC-side client of one cell: blocking commands, Status/CycleResult/plan progress as queues.

    Used by the tools that drive a cell the way a PLC would (``cellctl demo``, ``cellctl cmd``/``status``,
    ``cellctl replay --verify``, the cycle, fault and soak benches).
    It speaks only the wire contract (through :class:`CellLink`), so what works here works from a real PLC.

    Args:
        cfg: the cell config (endpoints, cell id).
        name: prefix of the request ids this client sends (shows up in Acks and logs).
        on_event: called with each Event (on a Zenoh thread: must not block).

    Raises:
        CellError: the bus cannot be reached.
    """

    def __init__(self, cfg: CellConfig, name: str = "plc", on_event: Callable[[Event], None] | None = None) -> None:
        self.cfg = cfg
        self.cell = cfg.cell_id
        self.name = name
        self.statuses: queue.Queue[Status] = queue.Queue()
        self.results: queue.Queue[CycleResult] = queue.Queue()
        self.progress: queue.Queue[PlanJobProgress] = queue.Queue()
        self.last_status: Status | None = None
        self._on_event = on_event
        # ids stay unique across this client's restarts: the supervisor refuses an id it already acted on
        self.ids = RequestIds(name)
        self.link = CellLink(cfg, [self.cell], self._sink, events=on_event is not None, progress=True)
        self.link.connect()

    @property
    def session(self) -> Any:
        """The link's Zenoh session (for a bench's own extra subscriptions and queries)."""
        return self.link.session

    def _sink(self, kind: str, cell: str, data: Any) -> None:
        if kind == "status":
            st = decode_as(Status, data)
            self.last_status = st
            self.statuses.put(st)
        elif kind == "result":
            self.results.put(decode_as(CycleResult, data))
        elif kind == "progress":
            self.progress.put(decode_as(PlanJobProgress, data))
        elif kind == "event" and self._on_event is not None:
            self._on_event(decode_as(Event, data))

    def next_id(self) -> str:
        """A fresh request id of this client (``{name}-{boot token}-{n}``)."""
        return self.ids.next()

    def command(self, name: CommandName, timeout: float = 10.0, **params: Any) -> Ack:
        """Send one PackML command by query and return its Ack.

        Raises:
            WorkerUnavailable: no daemon serves the cell's command key (the daemon is not running).
            WorkerTimeout: no Ack within ``timeout``.
        """
        return self.send(Command(command=name, request_id=self.next_id(), params=params, stamp=now_iso()), timeout)

    def unit_mode(self, mode: UnitModeName, timeout: float = 10.0, user: str | None = None) -> Ack:
        """Request a PackML unit mode (``production``, ``maintenance``, ``manual``) and return the Ack."""
        return self.send(Command(unit_mode=mode, user=user, request_id=self.next_id(), stamp=now_iso()), timeout)

    def send(self, cmd: Command, timeout: float = 10.0, *, put: bool = False) -> Ack:
        """Send a built Command and return its Ack: by query (the path with a guaranteed reply), or with
        ``put`` by put, the Ack read from ``cmd/ack`` (:meth:`CellLink.put`)."""
        if put:
            return self.link.put(self.cell, cmd, timeout)
        return self.link.send(self.cell, cmd, timeout)

    def wait_for(self, pred: Callable[[Status], bool], timeout: float) -> Status | None:
        """The first Status (from now on) that satisfies ``pred``, or None after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                st = self.statuses.get(timeout=min(0.5, max(0.01, deadline - time.monotonic())))
            except queue.Empty:
                continue
            if pred(st):
                return st
        return None

    def wait_workers(self, roles: list[str] | tuple[str, ...], timeout: float) -> bool:
        """True once a Status shows every role in ``roles`` alive."""
        if self.last_status is not None and all(self.last_status.workers.get(r) for r in roles):
            return True
        return self.wait_for(lambda s: all(s.workers.get(r) for r in roles), timeout) is not None

    def drain(self) -> None:
        """Forget queued Statuses and CycleResults (before starting something new)."""
        for q in (self.statuses, self.results):
            while not q.empty():
                q.get_nowait()

    def to_idle(self, timeout: float = 30.0) -> None:
        """Bring the cell to Idle from a wait state (Aborted → Clear, Stopped/Complete → Reset).

        Raises:
            CellError: Idle not reached (the reason names the state and the last error).
        """
        for _ in range(3):
            st = self.last_status or self.status(timeout)
            if st.state == "Idle":
                return
            cmd: CommandName = "clear" if st.state == "Aborted" else "reset"
            target = "Stopped" if cmd == "clear" else "Idle"
            ack = self.command(cmd)
            if not ack.accepted:
                raise CellError(f"cannot bring the cell to Idle: {cmd} refused in {st.state}: {ack.reason}")

            def reached(s: Status, t: str = target) -> bool:
                return s.state == t

            if self.wait_for(reached, timeout) is None:
                raise CellError(f"cell did not reach {target} within {timeout:g} s after {cmd}")
        raise CellError(f"cell did not reach Idle; it is in {self.last_status.state if self.last_status else '?'}")

    def run_cycle(self, timeout: float, **params: Any) -> CycleResult:
        """From Idle: Start, then the CycleResult once the cell rests in a wait state.

        Raises:
            CellError: Start refused, or no result within ``timeout``.
        """
        self.drain()
        ack = self.command("start", **params)
        if not ack.accepted:
            raise CellError(f"start refused: {ack.reason}")
        try:
            res = self.results.get(timeout=timeout)
        except queue.Empty:
            raise CellError(f"no cycle result within {timeout:g} s") from None
        # the result is published while Completing/Aborting; the next command needs the wait state
        self.wait_for(lambda s: s.state in ("Complete", "Aborted", "Stopped", "Held"), 30)
        return res

    def wait_plan_job(
        self, job_id: str, timeout: float, on_progress: Callable[[PlanJobProgress], None] | None = None
    ) -> PlanJobProgress | None:
        """Wait for planning job ``job_id`` to end; returns its last progress (state done/failed) or None."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                p = self.progress.get(timeout=1.0)
            except queue.Empty:
                continue
            if p.job_id != job_id:
                continue
            if on_progress is not None:
                on_progress(p)
            if p.state in ("done", "failed"):
                return p
        return None

    def status(self, timeout: float = 5.0) -> Status:
        """Query the current Status."""
        payload = self.link.query_status(self.cell, timeout)
        if payload is None:
            raise WorkerTimeout(f"no Status from cell {self.cell!r} within {timeout:g} s (daemon down?)")
        st = decode_as(Status, payload)
        self.last_status = st
        return st

    def close(self) -> None:
        self.link.close()

    def __enter__(self) -> PlcClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
