"""The supervisor: PackML machine ⊃ inspection cycle, driven by one dispatcher thread.

Concurrency model (why it looks like this):

* Zenoh callbacks only put events on :attr:`Supervisor._events` (never block, never call Zenoh).
* One dispatcher thread owns the ``transitions`` machine: it decodes commands, fires
  triggers, publishes Ack/Status, and reacts to liveliness changes and finished work.
* The work of an acting state (a cycle step or a PackML behaviour) runs on its own short-lived
  thread as a :class:`StepRun`; it reports back with a ``done`` event carrying its token.
  Any state change cancels the running activation, so a Stop/Abort/Hold is acted on at
  once even while a robot move is in flight; a late reply of a cancelled activation is
  ignored (stale token).
"""

from __future__ import annotations

import datetime as _dt
import itertools
import json
import logging
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zenoh
from transitions.extensions.nesting import HierarchicalMachine, NestedState

from cellctl.bus import keys
from cellctl.bus.codec import decode_as, encode
from cellctl.bus.rpc import request
from cellctl.config import CellConfig
from cellctl.errors import CellError, ProtocolError, TransitionRejected, WorkerError, WorkerUnavailable
from cellctl.messages import (
    Ack,
    BinInfo,
    Command,
    CycleOutcome,
    CycleResult,
    Event,
    EventLevel,
    PoseMsg,
    StartParams,
    Status,
    StopRequest,
)
from cellctl.recording.cycle_log import CycleLog
from cellctl.recording.index import CycleIndex, file_sha256
from cellctl.supervisor.context import Cancelled, CycleContext, StepRun
from cellctl.supervisor.definition import (
    CycleDefinition,
    Exit,
    PackMLDefinition,
    PackMLState,
    load_cycle,
    load_packml,
)
from cellctl.supervisor.steps import STEPS

__all__ = ["BEHAVIOURS", "Supervisor", "load_definitions"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

BEHAVIOURS = (
    "clear_faults",
    "open_cycle",
    "stop_cycle",
    "abort_cycle",
    "pause_cycle",
    "resume_check",
    "reset_cell",
    "finish_cycle",
)
"""PackML behaviours this code provides; ``states/packml.yaml`` may name only these."""

RECONCILE_S = 2.0
"""How often worker liveliness is re-read from the router (bounds a wrong count's lifetime)."""


class _CellState(NestedState):
    # '_' is transitions' default separator; our state names use it (checking_cache).
    separator = "."


class _CellMachine(HierarchicalMachine):
    state_cls = _CellState


class _Model:
    """The object ``transitions`` drives; it holds only ``state``."""

    state: str


def load_definitions(cfg_root: Path | None = None) -> tuple[PackMLDefinition, CycleDefinition]:
    """Load both YAML machines, validated against the behaviours and steps of this code."""
    root = cfg_root / "states" if cfg_root else None
    packml = load_packml(root / "packml.yaml" if root else None, BEHAVIOURS)
    cycle = load_cycle(root / "cycle.yaml" if root else None, {k: v.OUTCOMES for k, v in STEPS.items()})
    return packml, cycle


def validate_start_params(params: dict[str, Any]) -> dict[str, Any]:
    """Check Start params; raise ProtocolError naming the bad value."""
    return {**params, "mode": StartParams.from_params(params).mode}


class Supervisor:
    """The cell supervisor. Build it with :func:`cellctl.app.build_cell`.

    Args:
        cfg: the cell config.
        session: an open Zenoh session (router mode in the daemon).
        index: the cycle index.
        identify: ``identify(image_bgr, intrinsics, T_base_cam, catalog) -> Identification``.
        catalog: the bin catalog handed to ``identify``.
    """

    def __init__(
        self,
        cfg: CellConfig,
        session: Any,
        index: CycleIndex,
        *,
        identify: Callable[..., Any] | None = None,
        catalog: Any = None,
    ) -> None:
        self.cfg = cfg
        self.session = session
        self.index = index
        self.identify = identify
        self.catalog = catalog
        self.cell_id = cfg.cell_id
        self.packml, self.cycle = load_definitions(cfg.root)
        self.model = _Model()
        self.machine = self._build_machine()
        self._events: queue.Queue[tuple[Any, ...]] = queue.Queue()
        self._token = itertools.count(1)
        self._active: StepRun | None = None
        self._active_token = 0
        self._alive: dict[str, int] = {}
        self._ctx: CycleContext | None = None
        self._start_params: dict[str, Any] = {}
        self._cycle_seq = itertools.count(1)
        self.last_error: str | None = None
        self._status: Status | None = None
        self._thread: threading.Thread | None = None
        self._stopped = threading.Event()
        self._decls: list[Any] = []
        self._pub: dict[str, Any] = {}
        self.results: list[CycleResult] = []
        self.on_state_change: Callable[[Status], None] | None = None

    # --- machine ------------------------------------------------------------------------------

    def _build_machine(self) -> HierarchicalMachine:
        children = list(self.cycle.states)
        states: list[Any] = []
        for spec in self.packml.states.values():
            if spec.machine == "cycle":
                states.append({"name": spec.name, "children": children, "initial": self.cycle.initial})
            else:
                states.append(spec.name)
        transitions: list[dict[str, Any]] = []
        for cmd, table in self.packml.commands.items():
            for src, dest in table.items():
                transitions.append({"trigger": cmd, "source": src, "dest": dest})
        for src, dest in self.packml.state_complete.items():
            if dest == "Execute" and src != "Starting":
                # Unholding/Unsuspending resume the saved cycle step (transitions has no history states).
                for child in children:
                    transitions.append(
                        {
                            "trigger": "sc",
                            "source": src,
                            "dest": f"Execute.{child}",
                            "conditions": (lambda c=child: self._ctx is not None and self._ctx.saved_step == c),
                        }
                    )
                transitions.append({"trigger": "sc", "source": src, "dest": f"Execute.{self.cycle.initial}"})
            else:
                transitions.append({"trigger": "sc", "source": src, "dest": dest})
        exit_dest = {Exit.complete: "Completing", Exit.abort: "Aborting", Exit.hold: "Holding"}
        for st in self.cycle.states.values():
            for outcome, dest in st.on.items():
                target = exit_dest[dest] if isinstance(dest, Exit) else f"Execute.{dest}"
                transitions.append({"trigger": f"step_{outcome}", "source": f"Execute.{st.name}", "dest": target})
        return _CellMachine(
            model=self.model,
            states=states,
            transitions=transitions,
            initial=self.packml.initial,
            auto_transitions=False,
            queued=True,
            after_state_change=self._entered,
        )

    @property
    def state(self) -> str:
        """Full state name, e.g. ``Execute.scanning``."""
        return self.model.state

    @property
    def top_state(self) -> str:
        return self.model.state.split(".", 1)[0]

    @property
    def step(self) -> str | None:
        parts = self.model.state.split(".", 1)
        return parts[1] if len(parts) == 2 else None

    # --- life cycle ---------------------------------------------------------------------------

    def start(self) -> None:
        """Declare the bus interface and start the dispatcher thread (non-blocking)."""
        interrupted = self.index.mark_interrupted()
        if interrupted:
            ids = ", ".join(r.cycle_id for r in interrupted)
            self.last_error = f"cycle {ids} was interrupted (supervisor restarted); Reset to recover"
        s, c = self.session, self.cell_id
        put = self._events.put
        self._decls += [
            s.declare_subscriber(keys.cmd(c), lambda sample: put(("cmd", sample.payload.to_bytes(), None))),
            s.declare_queryable(keys.cmd(c), lambda q: put(("cmd", q.payload.to_bytes() if q.payload else b"", q))),
            s.declare_queryable(keys.status(c), lambda q: put(("status_query", q))),
            s.liveliness().declare_subscriber(
                keys.alive_all(c),
                lambda sample: put(("alive", str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)),
                history=True,
            ),
            s.liveliness().declare_token(keys.alive(c, "supervisor")),
        ]
        for name, key in (
            ("ack", keys.cmd_ack(c)),
            ("status", keys.status(c)),
            ("result", keys.result(c)),
            ("events", keys.events(c)),
        ):
            self._pub[name] = s.declare_publisher(key)
        self._thread = threading.Thread(target=self._loop, name="dispatcher", daemon=True)
        self._thread.start()
        threading.Thread(target=self._reconcile_alive, name="alive-reconcile", daemon=True).start()
        self._events.put(("publish_status",))

    def stop(self, timeout: float = 10.0) -> None:
        """Finish the open cycle's log, stop the dispatcher, undeclare everything."""
        if self._thread is None:
            return
        self._events.put(("shutdown",))
        self._thread.join(timeout)
        for d in reversed(self._decls):
            try:
                d.undeclare()
            except Exception:  # already closed with the session
                pass
        for p in self._pub.values():
            try:
                p.undeclare()
            except Exception:
                pass
        self._decls.clear()
        self._pub.clear()
        self._thread = None

    def __enter__(self) -> Supervisor:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def wait_stopped(self, timeout: float | None = None) -> bool:
        return self._stopped.wait(timeout)

    # --- dispatcher ---------------------------------------------------------------------------

    def _loop(self) -> None:
        period = self.cfg.supervisor.status_period_s
        next_beat = time.monotonic() + period
        while True:
            try:
                ev = self._events.get(timeout=max(0.0, next_beat - time.monotonic()))
            except queue.Empty:
                self._publish_status(record=False)
                next_beat = time.monotonic() + period
                continue
            try:
                if ev[0] == "shutdown":
                    self._shutdown_cycle()
                    self._stopped.set()
                    return
                self._dispatch(ev)
            except Exception:  # the dispatcher must survive any bug in one event
                log.exception("dispatcher failed on %s", ev[0])

    def _dispatch(self, ev: tuple[Any, ...]) -> None:
        kind = ev[0]
        if kind == "cmd":
            self._on_command(ev[1], ev[2])
        elif kind == "done":
            self._on_done(*ev[1:])
        elif kind == "alive":
            self._on_alive(ev[1], ev[2])
        elif kind == "status_query":
            q = ev[1]
            try:
                q.reply(q.key_expr, encode(self._make_status()))
            finally:
                q.drop()
        elif kind == "publish_status":
            self._publish_status()
        elif kind == "fire":
            self._fire(ev[1])
        elif kind == "alive_sync":
            self._on_alive_sync(ev[1])

    def _fire(self, trigger: str) -> None:
        getattr(self.model, trigger)()

    # --- commands -----------------------------------------------------------------------------

    def apply_command(self, payload: bytes) -> Ack:
        """Decode, check and apply one command; always returns an Ack (dispatcher thread only)."""
        try:
            cmd = decode_as(Command, payload, self.cfg.supervisor.max_command_bytes)
        except ProtocolError as err:
            return Ack(request_id=None, accepted=False, reason=str(err), state=self.top_state)
        name = cmd.name
        before = self.top_state
        allowed = self.packml.allowed_commands(before)
        if name not in allowed:
            reason = str(TransitionRejected(name, before, allowed))
            return Ack(request_id=cmd.request_id, command=name, accepted=False, reason=reason, state=before)
        if name == "start":
            try:
                self._start_params = validate_start_params(dict(cmd.params))
            except ProtocolError as err:
                return Ack(request_id=cmd.request_id, command=name, accepted=False, reason=str(err), state=before)
        elif cmd.params:
            return Ack(
                request_id=cmd.request_id,
                command=name,
                accepted=False,
                reason=f"command {name!r} takes no params, got {sorted(cmd.params)}",
                state=before,
            )
        if name in ("stop", "abort", "complete") and self._ctx is not None and not self._ctx.finished:
            self._ctx.reason = self._ctx.reason or f"{name} commanded in {self.state}"
        self._fire(name)
        return Ack(request_id=cmd.request_id, command=name, accepted=True, state=self.top_state)

    def _record_command(self, payload: bytes) -> None:
        """Log what was received: the command as sent, or a rejected payload as text (audit)."""
        assert self._ctx is not None
        try:
            is_command = isinstance(json.loads(payload), dict)
        except (ValueError, RecursionError):  # a rejected payload may be any bytes, nested arrays too
            is_command = False
        if is_command:
            self._ctx.log.write_json(keys.cmd(self.cell_id), "cellctl/Command", payload)
        else:
            raw = {"raw": payload[:1024].decode("utf-8", "replace"), "bytes": len(payload)}
            self._ctx.log.write_json(keys.cmd(self.cell_id), "cellctl.RejectedPayload", raw)

    def _on_command(self, payload: bytes, query: Any) -> None:
        ack = self.apply_command(payload)
        if self._ctx is not None and not self._ctx.finished:
            self._record_command(payload)
            self._ctx.log.write_message(keys.cmd_ack(self.cell_id), ack)
        if query is not None:
            try:
                query.reply(query.key_expr, encode(ack))
            finally:
                query.drop()
        else:
            self._pub["ack"].put(encode(ack))
        if not ack.accepted:
            log.info("command rejected: %s", ack.reason)

    # --- state entry: start the work of the new state ----------------------------------------

    def _entered(self) -> None:
        if self._active is not None:
            self._active.cancelled.set()
            self._active = None
        self._active_token = next(self._token)
        top, step = self.top_state, self.step
        spec = self.packml.states[top]
        if top == "Starting":
            self._create_cycle()
        # Status first: the activation may close the cycle log before the dispatcher runs again.
        self._publish_status()
        if step is not None:
            self._launch(step, self._run_step)
        elif spec.behaviour is not None:
            self._launch(spec.behaviour, getattr(self, f"_b_{spec.behaviour}"))
        elif top == "Complete" and self.cfg.supervisor.auto_reset:
            self._events.put(("fire", "reset"))

    def _launch(self, name: str, fn: Callable[[StepRun], str | None]) -> None:
        ctx = self._ctx or self._idle_context()
        run = StepRun(ctx, self._active_token, name)
        self._active = run

        def body() -> None:
            try:
                outcome = fn(run)
                self._events.put(("done", run.token, outcome, None))
            except Cancelled:
                pass
            except CellError as err:
                self._events.put(("done", run.token, "failed", str(err)))
            except Exception as err:
                log.exception("%s crashed", name)
                self._events.put(
                    ("done", run.token, "failed", f"internal error in {name}: {type(err).__name__}: {err}")
                )

        threading.Thread(target=body, name=f"run-{name}", daemon=True).start()

    def _run_step(self, run: StepRun) -> str:
        t0 = time.perf_counter()
        try:
            return STEPS[run.name]()(run)
        finally:
            sec = run.ctx.step_seconds
            sec[run.name] = sec.get(run.name, 0.0) + time.perf_counter() - t0

    def _on_done(self, token: int, outcome: str | None, reason: str | None) -> None:
        if token != self._active_token:
            return  # a cancelled activation finishing late
        self._active = None
        ctx = self._ctx
        if self.step is not None:
            if outcome == "failed" and ctx is not None:
                ctx.outcome = CycleOutcome.failed
                ctx.reason = reason
                self.last_error = reason
                self._event("error", f"{self.step} failed: {reason}")
            self._fire(f"step_{outcome}")
            return
        if outcome == "failed":
            self.last_error = reason
            self._event("error", f"{self.top_state} failed: {reason}")
            if ctx is not None and not ctx.finished:
                ctx.outcome = CycleOutcome.failed
                ctx.reason = reason
            if "abort" in self.packml.allowed_commands(self.top_state):
                self._fire("abort")
                return
        self._fire("sc")

    # --- liveliness ---------------------------------------------------------------------------

    def _on_alive(self, key: str, present: bool) -> None:
        role = keys.role_from_alive_key(self.cell_id, key)
        if role is None or role == "supervisor":
            return
        n = self._alive.get(role, 0) + (1 if present else -1)
        self._alive[role] = max(0, n)
        if self._alive[role] == 0 and role in self.cfg.supervisor.required_workers:
            self._worker_lost(role)
        self._publish_status()

    def _worker_lost(self, role: str) -> None:
        active = self.top_state in ("Starting", "Execute", "Unholding", "Unsuspending", "Completing")
        if not active:
            self._event("warning", f"{role} worker left (liveliness)")
            return
        reason = f"{role} worker lost (liveliness token gone) in {self.state}"
        self.last_error = reason
        self._event("error", reason)
        ctx = self._ctx
        if self.cfg.supervisor.on_worker_lost == "hold" and self.top_state == "Execute":
            if ctx is not None:
                ctx.saved_step = self.step
            self._fire("hold")
            return
        if ctx is not None and not ctx.finished:
            ctx.outcome = CycleOutcome.failed
            ctx.reason = reason
        self._fire("abort")

    def _query_alive(self) -> dict[str, int]:
        """Live tokens per role, asked from the router now (activation/reconcile threads only)."""
        counts: dict[str, int] = {}
        for r in self.session.liveliness().get(keys.alive_all(self.cell_id), timeout=1.0):
            if r.ok is not None:
                role = keys.role_from_alive_key(self.cell_id, str(r.ok.key_expr))
                if role is not None and role != "supervisor":
                    counts[role] = counts.get(role, 0) + 1
        return counts

    def _missing_workers(self) -> list[str]:
        """Required roles with no live token, asked now rather than taken from the event count."""
        try:
            alive = self._query_alive()
        except Exception:  # a closing session: fall back to what the events said
            alive = dict(self._alive)
        else:
            self._events.put(("alive_sync", alive))
        return [r for r in self.cfg.supervisor.required_workers if alive.get(r, 0) == 0]

    def _on_alive_sync(self, counts: dict[str, int]) -> None:
        # Liveliness events can arrive out of order around a reconnect (a frozen worker's late
        # DELETE after its new PUT for the same key); the router's answer is the truth.
        # Never an abort from here: losing a worker mid-cycle is the DELETE event's job.
        fresh = {r: counts.get(r, 0) for r in keys.ROLES}
        if any(fresh[r] != self._alive.get(r, 0) for r in keys.ROLES):
            log.info("worker liveliness corrected from the router: %s (events said %s)", fresh, self._alive)
            self._alive.update(fresh)
            self._publish_status()

    def _reconcile_alive(self) -> None:
        """Every few seconds, correct the worker counts from a liveliness query (own thread)."""
        while not self._stopped.wait(RECONCILE_S):
            try:
                self._events.put(("alive_sync", self._query_alive()))
            except Exception:  # the session is closing
                return

    # --- behaviours (run on activation threads) ----------------------------------------------

    def _idle_context(self) -> CycleContext:
        return CycleContext(cycle_id="", cfg=self.cfg, session=self.session, log=_NullLog())  # type: ignore[arg-type]

    def _b_clear_faults(self, run: StepRun) -> None:
        return None

    def _b_reset_cell(self, run: StepRun) -> None:
        self.last_error = None
        self._ctx = None

    def _b_open_cycle(self, run: StepRun) -> None:
        missing = self._missing_workers()
        if missing:
            raise WorkerUnavailable(f"no {', '.join(missing)} worker alive (liveliness); start the workers and retry")

    def _create_cycle(self) -> None:  # noqa: D401
        """Open the cycle's MCAP and index row (dispatcher thread, on entering Starting), so the
        Start command and its Ack are the first things the cycle log holds."""
        now = _dt.datetime.now(_dt.UTC)
        cycle_id = f"{now:%Y%m%dT%H%M%S}-{now.microsecond // 1000:03d}-{next(self._cycle_seq)}"
        rel = Path(self.cfg.recording.dir) / f"{now:%Y-%m-%d}" / f"{cycle_id}.mcap"
        path = self.cfg.path(rel)
        params = self._start_params
        # The row first: a crash between the two leaves a row that restart marks interrupted
        # (no log yet), never a log that no row accounts for (an orphan to the audit).
        self.index.begin(cycle_id, self.cell_id, str(path), now.isoformat(timespec="milliseconds"))
        clog = CycleLog(path, cycle_id, {"cell": self.cell_id, "mode": params.get("mode", "evaluate")})
        ctx = CycleContext(
            cycle_id=cycle_id,
            cfg=self.cfg,
            session=self.session,
            log=clog,
            mode=params.get("mode", "evaluate"),
            params=params,
            started=now.isoformat(timespec="milliseconds"),
            post_event=self._event,
            identify=self.identify,
            catalog=self.catalog,
        )
        ctx.log_rel = str(rel)  # type: ignore[attr-defined]
        self._ctx = ctx
        self._event("info", f"cycle {cycle_id} started ({ctx.mode})")

    def _b_resume_check(self, run: StepRun) -> None:
        missing = self._missing_workers()
        if missing:
            raise WorkerUnavailable(f"cannot resume: no {', '.join(missing)} worker alive")

    def _stop_robot(self, reason: str) -> None:
        if self._alive.get("robot", 0) == 0:
            return
        key = keys.robot_op(self.cell_id, "stop")
        msg = StopRequest(reason=reason)
        clog = self._ctx.log if self._ctx is not None and not self._ctx.finished else None
        try:
            if clog is not None:
                clog.write_message(f"{key}/request", msg)
            reply, _ = request(
                self.session, key, msg, StopRequest, timeout=self.cfg.supervisor.timeouts.stop, role="robot"
            )
            if clog is not None:
                clog.write_message(f"{key}/reply", reply)
        except (WorkerError, ProtocolError) as err:
            # A robot that cannot confirm the stop is logged loudly; the state machine still
            # goes to the safe state and commands no further motion.
            self._event("error", f"robot stop not confirmed: {err}")

    def _b_pause_cycle(self, run: StepRun) -> None:
        self._stop_robot("hold")

    def _b_stop_cycle(self, run: StepRun) -> None:
        self._stop_robot("stop")
        self._finalize(CycleOutcome.aborted, None)

    def _b_abort_cycle(self, run: StepRun) -> None:
        self._stop_robot("abort")
        self._finalize(CycleOutcome.aborted, None)

    def _b_finish_cycle(self, run: StepRun) -> None:
        ctx = self._ctx
        if ctx is not None and ctx.outcome is None:
            ctx.outcome = CycleOutcome.aborted
            ctx.reason = ctx.reason or "completed by command before the cycle ended"
        self._finalize(CycleOutcome.completed, None)

    def _finalize(self, default_outcome: CycleOutcome, reason: str | None) -> CycleResult | None:
        ctx = self._ctx
        if ctx is None or ctx.finished:
            return None
        ctx.finished = True
        ctx.shutdown()
        outcome = ctx.outcome or default_outcome
        res = CycleResult(
            cycle_id=ctx.cycle_id,
            outcome=outcome,
            reason=ctx.reason or reason,
            bin=BinInfo(
                type=ctx.bin_type, pose=PoseMsg.from_matrix(ctx.T_base_bin) if ctx.T_base_bin is not None else None
            ),
            plan_id=getattr(ctx.plan, "plan_id", None),
            plan_adjusted=getattr(ctx.plan, "adjusted", None),
            planner_job_id=ctx.planner_job_id,
            verdict=ctx.verdict if outcome == CycleOutcome.completed else None,
            viewpoints=ctx.viewpoints,
            coverage=ctx.coverage,
            dirt_map=ctx.dirt_map,
            log=getattr(ctx, "log_rel", None),
            timing={
                "steps_s": {k: round(v, 4) for k, v in ctx.step_seconds.items()},
                "rpc_s": {k: round(v, 4) for k, v in ctx.rpc_seconds.items()},
                "rpc_count": ctx.rpc_count,
            },
            started=ctx.started,
        )
        ctx.log.write_message(keys.result(self.cell_id), res)
        ctx.log.close({"outcome": outcome.value, "reason": res.reason or ""})
        self.index.finish(
            ctx.cycle_id,
            outcome.value,
            verdict=res.verdict,
            bin_type=ctx.bin_type,
            plan_id=res.plan_id,
            reason=res.reason,
            log_sha256=file_sha256(ctx.log.path),
            finished=res.finished,
        )
        if "result" in self._pub:
            self._pub["result"].put(encode(res))
        self.results.append(res)
        del self.results[:-50]
        return res

    def _shutdown_cycle(self) -> None:
        ctx = self._ctx
        if self._active is not None:
            self._active.cancelled.set()
        if ctx is not None and not ctx.finished:
            self._stop_robot("supervisor shutdown")
            ctx.outcome = ctx.outcome or CycleOutcome.aborted
            ctx.reason = ctx.reason or f"supervisor shut down in {self.state}"
            self.last_error = ctx.reason
            self._finalize(CycleOutcome.aborted, None)

    # --- status & events ----------------------------------------------------------------------

    def _make_status(self) -> Status:
        top = self.top_state
        return Status(
            cell=self.cell_id,
            state=top,
            state_code=PackMLState[top].value,
            step=self.step,
            cycle_id=self._ctx.cycle_id if self._ctx is not None else None,
            available_commands=self.packml.allowed_commands(top),
            last_error=self.last_error,
            workers={r: self._alive.get(r, 0) > 0 for r in keys.ROLES},
        )

    def _publish_status(self, record: bool = True) -> None:
        st = self._make_status()
        self._status = st
        if "status" in self._pub:
            self._pub["status"].put(encode(st))
        if record and self._ctx is not None and not self._ctx.finished:
            self._ctx.log.write_message(keys.status(self.cell_id), st)
        if self.on_state_change is not None and record:
            self.on_state_change(st)

    @property
    def status(self) -> Status:
        return self._status or self._make_status()

    def _event(self, level: str, text: str) -> None:
        ctx = self._ctx
        cycle_id = ctx.cycle_id if ctx is not None else None
        ev = Event(level=level, text=text, cycle_id=cycle_id)  # type: ignore[arg-type]
        if ctx is not None and not ctx.finished:
            ctx.log.event(int(EventLevel[level]), text)
        pub = self._pub.get("events")
        if pub is not None:
            pub.put(encode(ev))
        log.info("[%s] %s", level, text)


class _NullLog:
    """Stand-in log for activations outside a cycle (Resetting, Clearing): writes nothing."""

    path = Path("/dev/null")

    def write_json(self, *a: Any, **k: Any) -> None: ...
    def write_message(self, *a: Any, **k: Any) -> None: ...
    def event(self, *a: Any, **k: Any) -> None: ...
    def image(self, *a: Any, **k: Any) -> None: ...
    def close(self, *a: Any, **k: Any) -> None: ...
