"""The open cycle: its blackboard, its record, and how it ends (result, index row, Admin counters)."""

from __future__ import annotations

import datetime as _dt
import itertools
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Literal

import zenoh

from cellctl.bus import keys, topics
from cellctl.bus.rpc import request
from cellctl.config import CellConfig
from cellctl.errors import ProtocolError, WorkerError
from cellctl.messages import CycleOutcome, CycleResult, StartParams, StopRequest, WireMessage
from cellctl.recording.index import CycleIndex
from cellctl.supervisor.admin import AdminBook
from cellctl.supervisor.context import CycleContext, Identify
from cellctl.supervisor.health import StopReason
from cellctl.supervisor.publisher import Outbox
from cellctl.supervisor.recorder import CycleRecorder, NullRecorder, Recorder, assemble_result, new_cycle_id
from cellctl.workers.base import make_base

if TYPE_CHECKING:
    from cellctl.geometry.catalog import Catalog

__all__ = ["KEEP_RESULTS", "CycleKeeper"]

KEEP_RESULTS = 50
"""Finished results kept in memory (tests and benches read the last ones)."""
REASON_GRACE_S = 0.3
"""How long a cycle's close waits for the fault report of a worker whose token went first (the report
is sent 10 ms ahead of the withdrawal and normally arrives first; this covers the reordered case)."""


class CycleKeeper:
    """Opens, records and closes cycles; thread-safe where activations and the dispatcher meet.

    Args:
        robot_alive: whether a robot worker holds a liveliness token (no stop request otherwise).
    """

    def __init__(
        self,
        cfg: CellConfig,
        session: zenoh.Session | None,
        index: CycleIndex,
        outbox: Outbox,
        admin: AdminBook,
        robot_alive: Callable[[], bool],
        *,
        identify: Identify | None = None,
        catalog: Catalog | None = None,
    ) -> None:
        self.cfg = cfg
        self.session = session
        self.index = index
        self.outbox = outbox
        self.admin = admin
        self.robot_alive = robot_alive
        self.identify = identify
        self.catalog = catalog
        self.base = make_base(cfg)
        self.ctx: CycleContext | None = None
        self.start_params = StartParams()
        self.start_user: str | None = None
        """Who sent the Start (``Command.user``): a commissioning cycle records who declared the bin clean."""
        self.results: list[CycleResult] = []
        self._seq = itertools.count(1)
        self._lock = threading.Lock()  # finalize runs on activations and on the dispatcher (shutdown)
        self._reason_due: tuple[threading.Event, float] | None = None
        """(set when the report came, monotonic time of the loss) while a fault report is awaited."""

    @property
    def open_ctx(self) -> CycleContext | None:
        """The cycle's blackboard while its log is open, else None."""
        ctx = self.ctx
        return ctx if ctx is not None and not ctx.finished else None

    @property
    def record(self) -> Recorder | None:
        ctx = self.open_ctx
        return ctx.log if ctx is not None else None

    def write(self, key: str, msg: WireMessage) -> None:
        """Record ``msg`` on ``key`` in the open cycle's log (none open: nothing)."""
        if (rec := self.record) is not None:
            rec.write_message(key, msg)

    def interrupted(self) -> str | None:
        """Mark the cycles a previous run left open as interrupted (index); the reason to show, if any."""
        rows = self.index.mark_interrupted()
        if not rows:
            return None
        return f"cycle {', '.join(r.cycle_id for r in rows)} was interrupted (supervisor restarted); Reset to recover"

    def event(self, level: str, text: str) -> None:
        ctx = self.ctx
        self.outbox.announce(level, text, ctx.cycle_id if ctx is not None else None, self.record)

    def saved_step(self) -> str | None:
        """The cycle state Unhold/Unsuspend resume (set when a lost worker holds the cycle)."""
        return self.ctx.saved_step if self.ctx is not None else None

    def idle_context(self) -> CycleContext:
        """A blackboard for activations outside a cycle (Resetting, Clearing): records nothing."""
        return CycleContext(cycle_id="", cfg=self.cfg, session=self.session, log=NullRecorder())

    def open(self) -> CycleContext:
        """Open a cycle (dispatcher, on entering Starting): index row, MCAP, blackboard.

        Done before the Start Ack is sent, so the Start command and its Ack are the first things
        the cycle log holds.
        """
        now = _dt.datetime.now(_dt.UTC)
        cycle_id = new_cycle_id(now, next(self._seq))
        params = self.start_params
        rec = CycleRecorder(self.cfg, self.index, cycle_id, now, params.mode)
        self.ctx = CycleContext(
            cycle_id=cycle_id,
            cfg=self.cfg,
            session=self.session,
            log=rec,
            mode=params.mode,
            params=params,
            user=self.start_user,
            started=now.isoformat(timespec="milliseconds"),
            log_rel=rec.rel,
            post_event=self.event,
            identify=self.identify,
            catalog=self.catalog,
            base=self.base,
        )
        self.event("info", f"cycle {cycle_id} started ({params.mode})")
        return self.ctx

    def note(self, reason: str, *, failed: bool = False) -> None:
        """Give the open cycle its reason (the first one wins); ``failed`` also sets outcome failed."""
        ctx = self.open_ctx
        if ctx is None:
            return
        if failed:
            ctx.result.outcome, ctx.result.reason = CycleOutcome.failed, reason
        else:
            ctx.result.reason = ctx.result.reason or reason

    def expect_reason(self) -> None:
        """A worker was lost without its fault report yet (dispatcher): the close waits for it a moment."""
        self._reason_due = (threading.Event(), time.monotonic())

    def reason_arrived(self) -> None:
        """The awaited fault report came (dispatcher): the reason is in place, the close may go on."""
        due, self._reason_due = self._reason_due, None
        if due is not None:
            due[0].set()

    def correct_reason(self, old: StopReason, new: StopReason) -> Literal["open", "sealed"] | None:
        """Give the cycle that stopped with ``old`` the reason ``new``: the open cycle (``"open"``), or a
        closed one where it is still mutable, the results kept in memory (``"sealed"``: its log and index
        row are not; a warning event says so). None: no cycle still carries ``old``."""
        ctx = self.open_ctx
        if ctx is not None and ctx.result.reason is old:
            ctx.result.reason = new
            return "open"
        for i, res in enumerate(self.results):
            # a result holds the reason's text (it went over the wire); the cycle id makes it this loss's
            if old.cycle_id is not None and res.cycle_id == old.cycle_id and res.reason == old:
                self.results[i] = res.model_copy(update={"reason": new})
                # closed before the report came: its log and index row are sealed (sha256, hash chain)
                self.event(
                    "warning",
                    f"cycle {old.cycle_id}: the {old.role} fault report came after the cycle closed; its reason is "
                    f"{str(new)!r} (the cycle's log and index row keep {str(old)!r})",
                )
                return "sealed"
        return None

    def finalize(self, default_outcome: CycleOutcome, reason: str | None = None) -> CycleResult | None:
        """Close the open cycle: result into the log, log closed, index row closed, result published."""
        due = self._reason_due
        if due is not None and threading.current_thread().name != "dispatcher":  # the dispatcher sets it
            due[0].wait(max(0.0, due[1] + REASON_GRACE_S - time.monotonic()))  # the report corrects the reason
        self._reason_due = None
        with self._lock:
            ctx = self.open_ctx
            if ctx is None:
                return None
            ctx.finished = True
        ctx.shutdown()
        if ctx.refs.writer is not None:  # a commissioning cycle that ended before its set was claimed
            ctx.refs.writer.discard()
        res = assemble_result(ctx, default_outcome, reason)
        ctx.log.close(res)
        self.outbox.result(res)
        self.admin.cycle_finished(res)
        self.results.append(res)
        del self.results[:-KEEP_RESULTS]
        return res

    def stop_robot(self, reason: str) -> None:
        """Ask the robot to stop now, recorded in the open cycle's log; never raises."""
        if not self.robot_alive() or self.session is None:
            return
        key = keys.robot_op(self.cfg.cell_id, "stop")
        msg = StopRequest(reason=reason)
        rec = self.record
        try:
            if rec is not None:
                rec.write_message(topics.request(key), msg)
            reply, _ = request(
                self.session, key, msg, StopRequest, timeout=self.cfg.supervisor.timeouts.stop, role="robot"
            )
            if rec is not None:
                rec.write_message(topics.reply(key), reply)
        except (WorkerError, ProtocolError) as err:
            # A robot that cannot confirm the stop is logged loudly; the state machine still
            # goes to the safe state and commands no further motion.
            self.event("error", f"robot stop not confirmed: {err}")

    def shutdown(self, state: str) -> str | None:
        """Close an open cycle as aborted because the supervisor stops; return the reason, if any."""
        ctx = self.open_ctx
        if ctx is None:
            return None
        self.stop_robot("supervisor shutdown")
        ctx.result.outcome = ctx.result.outcome or CycleOutcome.aborted
        ctx.result.reason = ctx.result.reason or f"supervisor shut down in {state}"
        self.finalize(CycleOutcome.aborted)
        return ctx.result.reason

    def reset(self) -> None:
        self.ctx = None
