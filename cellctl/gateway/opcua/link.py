"""The gateway's Zenoh side: one client session of the wire contract, reopened until the router is there.

Commands go by query, so each accepted OPC UA request is exactly one Command and its Ack. Status,
CycleResult, Event and the supervisor's liveliness arrive on Zenoh threads and are handed to
``sink`` at once (it must not block: the gateway passes them to its event loop).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

import zenoh

from cellctl.bus import keys
from cellctl.bus.codec import decode_as, encode
from cellctl.bus.session import open_session
from cellctl.config import CellConfig
from cellctl.errors import CellError, ProtocolError, WorkerTimeout, WorkerUnavailable
from cellctl.messages import Ack, Command

__all__ = ["CellLink", "Sink"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

Sink = Callable[[str, str, Any], None]
"""``sink(kind, cell, data)``: kind ``status``/``result``/``event`` (payload bytes), ``alive`` (bool),
or ``link`` (cell ``""``, data: None when connected, else the reason)."""


class CellLink:
    """A Zenoh client session serving one or more cells to the gateway.

    Args:
        cfg: the cell config (bus endpoints, security); the session is opened as ``cfg.bus.principal``.
        cells: the cell ids whose keys are subscribed.
        sink: receives every sample (see :data:`Sink`); called on Zenoh threads.
        reconnect_s: retry period while the router cannot be reached.
    """

    def __init__(self, cfg: CellConfig, cells: list[str], sink: Sink, reconnect_s: float = 1.0) -> None:
        self.cfg = cfg
        self.cells = list(cells)
        self._sink = sink
        self._reconnect_s = reconnect_s
        self._session: Any = None
        self._handles: list[Any] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="opcua-zenoh-link", daemon=True)
        self.last_error: str | None = None

    def start(self) -> None:
        self._thread.start()

    @property
    def connected(self) -> bool:
        return self._session is not None

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                session = open_session(self.cfg, "client")
            except CellError as err:
                if self.last_error != str(err):
                    log.warning("bus not reachable (retrying every %.1f s): %s", self._reconnect_s, err)
                self.last_error = str(err)
                self._sink("link", "", f"not connected to the cell bus: {err}")
                self._stop.wait(self._reconnect_s)
                continue
            try:
                self._declare(session)
            except Exception as err:  # a refused declaration must not kill the link thread
                log.exception("cannot subscribe on the cell bus")
                self._sink("link", "", f"cannot subscribe on the cell bus: {err}")
                session.close()
                self._stop.wait(self._reconnect_s)
                continue
            self._session = session
            self.last_error = None
            self._sink("link", "", None)
            log.info("connected to the cell bus %s as %r", self.cfg.bus.connect, self.cfg.bus.principal)
            # Zenoh's client reconnects to a restarted router by itself; the session stays valid.
            self._stop.wait()

    def _declare(self, session: Any) -> None:
        sink = self._sink
        for cell in self.cells:
            for kind, key in (
                ("status", keys.status(cell)),
                ("result", keys.result(cell)),
                ("event", keys.events(cell)),
            ):
                self._handles.append(
                    session.declare_subscriber(key, lambda s, k=kind, c=cell: sink(k, c, s.payload.to_bytes()))
                )
            self._handles.append(
                session.liveliness().declare_subscriber(
                    keys.alive(cell, "supervisor"),
                    lambda s, c=cell: sink("alive", c, s.kind == zenoh.SampleKind.PUT),
                    history=True,
                )
            )

    def command(self, cell: str, cmd: Command, timeout: float, done: Callable[[Ack | CellError], None]) -> None:
        """Send ``cmd`` to ``cell`` by query without blocking; ``done`` gets its Ack or the error.

        ``done`` runs once, on a Zenoh thread, when the query is finished (replies in or timed out):
        the caller's thread sends the query itself, with no hand-over to another thread first, which
        is on the path of every command's StateCurrent change. The errors: WorkerUnavailable (not
        connected, or no daemon serves the key), WorkerTimeout (no answer within ``timeout``),
        ProtocolError (the reply is not an Ack).
        """
        session = self._session
        key = keys.cmd(cell)
        if session is None:
            done(WorkerUnavailable(f"not connected to the cell bus {self.cfg.bus.connect}: {self.last_error}"))
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
        return replies[0].ok.payload.to_bytes()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        session, self._session = self._session, None
        for h in self._handles:
            try:
                h.undeclare()
            except Exception:  # the session may already be gone
                pass
        self._handles.clear()
        if session is not None:
            session.close()
