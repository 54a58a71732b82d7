"""The supervisor: PackML machine ⊃ inspection cycle, driven by one dispatcher thread.

Concurrency model (why it looks like this):

* Zenoh callbacks only put typed events (:mod:`.events`) on the queue (never block, never call Zenoh).
* One dispatcher thread owns the ``transitions`` machine (:mod:`.machine`): it checks commands
  (:mod:`.commands`), fires triggers or runs a registered handler (:mod:`.command_handlers`),
  publishes Ack/Status (:mod:`.publisher`), and reacts to liveliness (:mod:`.roster`), fault
  reports joined to losses (:mod:`.health`) and finished work.
* The work of an acting state (a cycle step of :mod:`.steps` or a PackML behaviour of
  :mod:`.behaviours`) runs on its own short-lived thread (:mod:`.runner`); any state change
  cancels it. The open cycle, its log and its result are :mod:`.cycles` / :mod:`.recorder`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from cellctl.bus import keys
from cellctl.bus.codec import encode
from cellctl.config import CellConfig
from cellctl.errors import CellError
from cellctl.messages import Ack, CycleResult, Status, UnitMode
from cellctl.recording.index import CycleIndex
from cellctl.supervisor import events
from cellctl.supervisor.admin import AdminBook
from cellctl.supervisor.behaviours import BEHAVIOUR_CLASSES, BEHAVIOURS
from cellctl.supervisor.command_handlers import HANDLERS
from cellctl.supervisor.commands import Accepted, check_command, recorded_command
from cellctl.supervisor.context import Identify
from cellctl.supervisor.cycles import CycleKeeper
from cellctl.supervisor.dispatcher import Dispatcher
from cellctl.supervisor.health import FaultExplainsLoss, WorkerHealth
from cellctl.supervisor.inbox import declare_inbox, undeclare_all
from cellctl.supervisor.machine import CellModel, build_machine
from cellctl.supervisor.publisher import Outbox, make_status, reply
from cellctl.supervisor.registry import load_definitions
from cellctl.supervisor.replay_guard import ReplayGuard
from cellctl.supervisor.roster import ACTIVE_STATES, RECONCILE_S, WorkerRoster, liveliness_query
from cellctl.supervisor.runner import Runner, run_step
from cellctl.supervisor.steps import STEPS
from cellctl.supervisor.unit_modes import commands_in_mode

if TYPE_CHECKING:
    import zenoh

    from cellctl.geometry.catalog import Catalog

__all__ = ["BEHAVIOURS", "Supervisor", "load_definitions"]

class Supervisor(Dispatcher):
    """The cell supervisor. Build it with :func:`cellctl.app.build_cell`.

    Args:
        cfg: the cell config.
        session: an open Zenoh session (router mode in the daemon); None for a machine without bus.
        index: the cycle index (the Admin counters start from it).
        identify: ``identify(image_bgr, intrinsics, T_base_cam, catalog) -> Identification``.
        catalog: the bin catalog handed to ``identify``.
    """

    def __init__(
        self, cfg: CellConfig, session: zenoh.Session | None, index: CycleIndex, *,
        identify: Identify | None = None, catalog: Catalog | None = None,
    ) -> None:  # fmt: skip
        super().__init__(cfg.supervisor.status_period_s)
        self.cfg, self.session, self.index, self.catalog = cfg, session, index, catalog
        self.cell_id = cfg.cell_id
        self.packml, self.cycle = load_definitions(cfg.root)
        self.roster = WorkerRoster(cfg.cell_id, cfg.supervisor.required_workers, liveliness_query(session, cfg.cell_id))
        self.outbox = Outbox(session, cfg.cell_id)
        self.admin = AdminBook(index)
        self.cycles = CycleKeeper(
            cfg, session, index, self.outbox, self.admin, lambda: self.roster.count("robot") > 0,
            identify=identify, catalog=catalog,
        )  # fmt: skip
        self.runner = Runner(self._events.put)
        self.model = CellModel()
        self.machine = build_machine(self.packml, self.cycle, self.model, self.cycles.saved_step, self._entered)
        self.unit_mode = UnitMode.production
        self.replay_guard = ReplayGuard()
        self.last_error: str | None = None
        self.on_state_change: Callable[[Status], None] | None = None
        self._status: Status | None = None
        self._decls: list[Any] = []
        self.health = WorkerHealth(on_report=lambda m: self.cycles.write(keys.worker_fault(self.cell_id, m.role), m))

    @property
    def state(self) -> str:
        """Full state name, e.g. ``Execute.scanning``."""
        return self.model.state

    @property
    def top_state(self) -> str:
        return self.model.top

    @property
    def results(self) -> list[CycleResult]:
        return self.cycles.results

    def start(self) -> None:
        """Declare the bus interface and start the dispatcher thread (non-blocking)."""
        if (interrupted := self.cycles.interrupted()) is not None:
            self.last_error = self.admin.stop_reason = interrupted
        self._decls = declare_inbox(self.session, self.cell_id, self._events.put)
        self.outbox.declare()
        self._start_dispatcher()
        reconcile = (RECONCILE_S, self._stopped, self._events.put)
        threading.Thread(target=self.roster.reconcile, args=reconcile, name="alive-reconcile", daemon=True).start()
        self._events.put(events.PublishStatus())

    def stop(self, timeout: float = 10.0) -> None:
        """Finish the open cycle's log, stop the dispatcher, undeclare everything."""
        if self._stop_dispatcher(timeout):
            undeclare_all(self._decls)
            self.outbox.undeclare()

    def _beat(self) -> None:
        self._publish_status(record=False)

    def _shutdown(self) -> None:
        self.runner.cancel()
        self.last_error = self.cycles.shutdown(self.state) or self.last_error

    def _dispatch(self, ev: events.DispatchEvent) -> None:
        match ev:
            case events.CommandReceived(payload, query):
                self._on_command(payload, query)
            case events.StepDone():
                self._on_done(ev)
            case events.AliveChanged(key, present):
                self._on_alive(key, present)
            case events.EventReceived(payload):
                if (explained := self.health.report(payload)) is not None:
                    self._fault_explains_loss(explained)
            case events.AliveSync(counts):
                if self.roster.sync(counts):
                    self._publish_status()
            case events.StatusQuery(query):
                reply(query, encode(self._make_status()))
            case events.PublishStatus():
                self._publish_status()
            case events.Fire(trigger):
                self.model.trigger(trigger)

    def apply_command(self, payload: bytes) -> Ack:
        """Decode, check and apply one command; always returns an Ack (dispatcher thread only)."""
        before = self.top_state
        checked = check_command(
            payload, max_bytes=self.cfg.supervisor.max_command_bytes, state=before,
            allowed=self.packml.allowed_commands(before), mode=self.unit_mode,
        )  # fmt: skip
        if not isinstance(checked, Accepted):
            return checked
        if refusal := self.replay_guard.refusal(checked.cmd):
            return checked.refuse(before, refusal, self.unit_mode)
        ack = self._apply(checked, before)
        if ack.accepted:
            self.replay_guard.acted(checked.cmd)
        return ack

    def _apply(self, checked: Accepted, before: str) -> Ack:
        cmd, by = checked.cmd, f" by {checked.cmd.user}" if checked.cmd.user else ""
        if (handler := HANDLERS.get(cmd.name)) is not None:  # a command that moves no PackML state
            try:
                done = handler(self.cycles, checked)
            except CellError as err:
                return checked.refuse(before, str(err), self.unit_mode)
            self.cycles.event("info", f"{done}{by}")
            return checked.ack(before, self.unit_mode)
        if checked.mode is not None:
            self.unit_mode = checked.mode
            self.cycles.event("info", f"unit mode {checked.mode.name}{by}")
            self._publish_status()
            return checked.ack(before)
        name = cmd.name
        if checked.start is not None:
            self.cycles.start_params, self.cycles.start_user = checked.start, cmd.user
        if name in ("stop", "abort", "hold"):
            self.admin.stop_reason = f"{name} commanded in {self.state}{by}"
        if name in ("stop", "abort", "complete"):
            self.cycles.note(f"{name} commanded in {self.state}")
        self.model.trigger(name)
        return checked.ack(self.top_state, self.unit_mode)

    def _on_command(self, payload: bytes, query: events.Query | None) -> None:
        ack = self.apply_command(payload)
        if (rec := self.cycles.record) is not None:
            rec.write_json(keys.cmd(self.cell_id), *recorded_command(payload))
            rec.write_message(keys.cmd_ack(self.cell_id), ack)
        self.outbox.ack(ack, query)

    def _entered(self) -> None:
        self.runner.cancel()
        top, state = self.top_state, self.model.step
        if top == "Starting":
            self.cycles.open()
        # Status first: the activation may close the cycle log before the dispatcher runs again.
        self._publish_status()
        ctx = self.cycles.ctx or self.cycles.idle_context()
        behaviour = self.packml.states[top].behaviour
        if state is not None:
            step = STEPS[self.cycle.states[state].step]  # the step the cycle state names
            self.runner.launch(state, ctx, lambda run: run_step(step, run))
        elif behaviour is not None:
            work = BEHAVIOUR_CLASSES[behaviour]()
            self.runner.launch(behaviour, ctx, lambda run: work.execute(run, self))
        elif top == "Complete" and self.cfg.supervisor.auto_reset:
            self._events.put(events.Fire("reset"))

    def _on_done(self, ev: events.StepDone) -> None:
        if not self.runner.finished(ev):
            return  # a cancelled activation finishing late
        where = self.model.step or self.top_state
        if ev.outcome == "failed":
            self.last_error = ev.reason
            self.cycles.event("error", f"{where} failed: {ev.reason}")
            self.cycles.note(ev.reason or "failed", failed=True)
        if self.model.step is not None:
            if ev.outcome == "failed":
                self.admin.stop_reason = ev.reason
            self.model.trigger(f"step_{ev.outcome}")
            return
        if ev.outcome == "failed" and "abort" in self.packml.allowed_commands(self.top_state):
            self.admin.stop_reason = ev.reason
            self.model.trigger("abort")
            return
        self.model.trigger("sc")

    def missing_workers(self) -> list[str]:
        """Required roles with no live token, asked from the router now (activation threads)."""
        return self.roster.missing(lambda counts: self._events.put(events.AliveSync(counts)))

    def reset_cell(self) -> None:
        self.last_error = None
        self.cycles.reset()

    def _on_alive(self, key: str, present: bool) -> None:
        role = self.roster.changed(key, present)
        if role is None:
            return
        if self.roster.lost(role):
            self._worker_lost(role)
        self._publish_status()

    def _worker_lost(self, role: str) -> None:
        if self.top_state not in ACTIVE_STATES:
            self.cycles.event("warning", f"{role} worker left (liveliness)")
            return
        ctx = self.cycles.open_ctx
        reason = self.health.loss(role, self.state, ctx.cycle_id if ctx is not None else None)
        if reason.fault is None:
            # a fault report may be just behind the loss (Zenoh orders a put and an undeclaration
            # apart): the cycle's close waits a moment for it, so the sealed record names the fault
            self.cycles.expect_reason()
        self.last_error = self.admin.stop_reason = reason
        self.cycles.event("error", reason)
        if self.cfg.supervisor.on_worker_lost == "hold" and self.top_state == "Execute":
            if ctx is not None:
                ctx.saved_step = self.model.step
            self.model.trigger("hold")
            return
        self.cycles.note(reason, failed=True)
        self.model.trigger("abort")

    def _fault_explains_loss(self, ev: FaultExplainsLoss) -> None:
        """The loss's reason, wherever it went (the cycle, last error, stop reason), becomes the fault's."""
        self.cycles.correct_reason(ev.before, ev.after)
        self.cycles.reason_arrived()
        if self.last_error is ev.before:
            self.last_error = ev.after
        if self.admin.stop_reason is ev.before:
            self.admin.stop_reason = ev.after
        self._publish_status()

    def _make_status(self) -> Status:
        ctx = self.cycles.ctx
        missing = [f"{r} worker not alive" for r, up in self.roster.workers().items() if not up]
        return make_status(
            self.cell_id, self.state, cycle_id=ctx.cycle_id if ctx is not None else None,
            available=commands_in_mode(self.packml.allowed_commands(self.top_state), self.unit_mode),
            last_error=self.last_error, workers=self.roster.workers(), mode=self.unit_mode,
            admin=self.admin.snapshot(missing),
        )  # fmt: skip

    def _publish_status(self, record: bool = True) -> None:
        st = self._make_status()
        self._status = st
        self.outbox.status(st)
        if record:
            self.cycles.write(keys.status(self.cell_id), st)
        if self.on_state_change is not None and record:
            self.on_state_change(st)

    @property
    def status(self) -> Status:
        return self._status or self._make_status()

