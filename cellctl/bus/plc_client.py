"""A PLC-side client of the cell: commands by query, Status/CycleResult/plan progress as queues.

Used by the tools that drive a cell the way a PLC would (``cellctl demo``, the cycle, fault and
soak benches). It speaks only the wire contract, so what works here works from a real PLC.
"""

from __future__ import annotations

import itertools
import queue
import secrets
import time
from collections.abc import Callable
from typing import Any

import zenoh

from cellctl.bus import keys
from cellctl.bus.codec import decode_as, encode
from cellctl.bus.session import open_session
from cellctl.config import CellConfig
from cellctl.errors import CellError, WorkerTimeout
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

__all__ = ["PlcClient"]


class PlcClient:
    """Commands, Status, CycleResults, Events and planning progress of one cell.

    Args:
        cfg: the cell config (endpoints, cell id).
        name: prefix of the request ids this client sends (shows up in Acks and logs).
        on_event: called with each Event (on a Zenoh thread: must not block).
    """

    def __init__(self, cfg: CellConfig, name: str = "plc", on_event: Callable[[Event], None] | None = None) -> None:
        self.cfg = cfg
        self.cell = cfg.cell_id
        self.name = name
        self.session = open_session(cfg, "client")
        self.statuses: queue.Queue[Status] = queue.Queue()
        self.results: queue.Queue[CycleResult] = queue.Queue()
        self.progress: queue.Queue[PlanJobProgress] = queue.Queue()
        self.last_status: Status | None = None
        self._seq = itertools.count(1)
        # ids stay unique across this client's restarts: the supervisor refuses an id it already acted on
        self._boot = secrets.token_hex(3)
        c = self.cell

        def on_status(sample: Any) -> None:
            st = decode_as(Status, sample.payload.to_bytes())
            self.last_status = st
            self.statuses.put(st)

        self._subs = [
            self.session.declare_subscriber(keys.status(c), on_status),
            self.session.declare_subscriber(
                keys.result(c), lambda s: self.results.put(decode_as(CycleResult, s.payload.to_bytes()))
            ),
            self.session.declare_subscriber(
                keys.planner_job_progress(c),
                lambda s: self.progress.put(decode_as(PlanJobProgress, s.payload.to_bytes())),
            ),
        ]
        if on_event is not None:
            self._subs.append(
                self.session.declare_subscriber(
                    keys.events(c), lambda s: on_event(decode_as(Event, s.payload.to_bytes()))
                )
            )

    def command(self, name: CommandName, timeout: float = 10.0, **params: Any) -> Ack:
        """Send one PackML command by query and return its Ack.

        Raises:
            WorkerTimeout: no Ack within ``timeout`` (the daemon is not running or not answering).
        """
        return self.send(Command(command=name, request_id=self._next_id(), params=params, stamp=now_iso()), timeout)

    def unit_mode(self, mode: UnitModeName, timeout: float = 10.0, user: str | None = None) -> Ack:
        """Request a PackML unit mode (``production``, ``maintenance``, ``manual``) and return the Ack."""
        return self.send(Command(unit_mode=mode, user=user, request_id=self._next_id(), stamp=now_iso()), timeout)

    def _next_id(self) -> str:
        return f"{self.name}-{self._boot}-{next(self._seq)}"

    def send(self, cmd: Command, timeout: float = 10.0) -> Ack:
        """Send a built Command by query (the path with a guaranteed reply) and return its Ack."""
        replies = list(
            self.session.get(
                keys.cmd(self.cell),
                payload=encode(cmd),
                timeout=timeout,
                congestion_control=zenoh.CongestionControl.BLOCK,
            )
        )
        if not replies or replies[0].ok is None:
            raise WorkerTimeout(f"no Ack for {cmd.name!r} from cell {self.cell!r} within {timeout:g} s (daemon down?)")
        return decode_as(Ack, replies[0].ok.payload.to_bytes())

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
        replies = list(self.session.get(keys.status(self.cell), timeout=timeout))
        if not replies or replies[0].ok is None:
            raise WorkerTimeout(f"no Status from cell {self.cell!r} within {timeout:g} s (daemon down?)")
        st = decode_as(Status, replies[0].ok.payload.to_bytes())
        self.last_status = st
        return st

    def close(self) -> None:
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:  # the session may already be gone
                pass
        self.session.close()

    def __enter__(self) -> PlcClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
