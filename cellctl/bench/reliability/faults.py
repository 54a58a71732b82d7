"""Fault injection: kill (SIGKILL) or freeze (SIGSTOP) a worker process at a cycle step.

:class:`FaultInjector` drives a running cell like a PLC, sends the signal to the worker's
process the moment a Status shows the cycle in the chosen step, and then checks what a plant
engineer would check:

* **detection**: the first warning/error Event naming the worker after the signal (arrival
  time) — a killed worker's liveliness token goes at once, a frozen one's when its link lease
  (``bus.lease_ms``) expires;
* **safe state**: the cell rests in Aborted (or Held, by ``supervisor.on_worker_lost``) — or
  in Complete with a good record, when the rest of the cycle did not need the worker and ended
  before the fault could be noticed;
* **no further motion**: no approach/move request is logged after the detection, and the arm
  (asked through ``robot/state``) does not move after the safe state — for a frozen robot,
  after it resumed;
* **record**: the partial cycle's CycleResult says ``failed`` and names the worker;
* **recovery**: once the worker is back (restarted after a kill, SIGCONT after a freeze),
  Clear/Reset/Start runs a good cycle.

``cellctl bench faults`` runs the matrix on the sim cell; the tests run it on worker doubles.
"""

from __future__ import annotations

import os
import queue
import signal
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

from cellctl.bench.options import BenchOptions
from cellctl.bus import keys, topics
from cellctl.bus.codec import decode_as
from cellctl.bus.plc_client import PlcClient
from cellctl.bus.rpc import request
from cellctl.config import CellConfig
from cellctl.errors import CellError
from cellctl.messages import Event, RobotState, RobotStateRequest

__all__ = ["FAULTS", "FaultCase", "FaultInjector", "FaultCaseResult", "WorkerControl", "bench_faults"]

FAULTS = {"kill": signal.SIGKILL, "freeze": signal.SIGSTOP}
SAFE_STATES = ("Aborted", "Held", "Stopped")
MOTION_OPS = ("approach", "move")


class WorkerControl(Protocol):
    """Where the worker processes are, and how to bring a killed one back."""

    def pid(self, role: str) -> int: ...

    def restart(self, role: str) -> None: ...


@dataclass(frozen=True)
class FaultCase:
    role: str
    fault: str  # a key of FAULTS
    step: str

    @property
    def name(self) -> str:
        return f"{self.fault} {self.role} in {self.step}"


@dataclass
class FaultCaseResult:
    """What happened in one case; ``problems`` empty means the cell behaved."""

    case: FaultCase
    injected_in: str | None = None
    detection_s: float | None = None
    detected_by: str | None = None
    safe_state: str | None = None
    safe_s: float | None = None
    outcome: str | None = None
    reason: str | None = None
    motion_requests_after_detection: int = 0
    robot_moved_rad: float | None = None
    recovery_outcome: str | None = None
    recovery_s: float | None = None
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["case"] = self.case.name
        d["ok"] = self.ok
        for k in ("detection_s", "safe_s", "recovery_s", "robot_moved_rad"):
            if d[k] is not None:
                d[k] = round(d[k], 4)
        return d


class _Events:
    """Warning/error Events of the cell with their arrival time (wall clock, ns)."""

    def __init__(self, plc: PlcClient) -> None:
        self._cond = threading.Condition()
        self._seen: list[tuple[int, Event]] = []

        def on(sample: Any) -> None:
            ev = decode_as(Event, sample.payload.to_bytes())
            if ev.level in ("warning", "error", "fatal"):
                with self._cond:
                    self._seen.append((time.time_ns(), ev))
                    del self._seen[:-200]
                    self._cond.notify_all()

        self._sub = plc.session.declare_subscriber(keys.events(plc.cell), on)

    def first_after(self, t_ns: int, word: str, timeout: float) -> tuple[int, str] | None:
        """The first warning/error after ``t_ns`` whose text names ``word``: (arrival ns, text)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                for t, ev in self._seen:
                    if t >= t_ns and word in ev.text:
                        return t, ev.text[:160]
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)

    def close(self) -> None:
        self._sub.undeclare()


class FaultInjector:
    """Runs fault cases against a live cell.

    Args:
        cfg: the cell config (for its logs and lease).
        plc: a PLC client of the cell.
        workers: the worker processes.
        cycle_timeout: seconds a (good or partial) cycle may take.
        good_outcomes: outcomes that count as a good recovery cycle.
    """

    def __init__(
        self,
        cfg: CellConfig,
        plc: PlcClient,
        workers: WorkerControl,
        *,
        cycle_timeout: float = 300.0,
        good_outcomes: tuple[str, ...] = ("completed",),
    ) -> None:
        self.cfg = cfg
        self.plc = plc
        self.workers = workers
        self.cycle_timeout = cycle_timeout
        self.good_outcomes = good_outcomes
        self.detect_bound_s = {"kill": 1.0, "freeze": cfg.bus.lease_ms / 1000 + 1.0}
        """The bound promised per fault: liveliness loss at once / after one lease (+ 1 s margin)."""
        self._events = _Events(plc)

    def close(self) -> None:
        self._events.close()

    def run(self, case: FaultCase, attempts: int = 3) -> FaultCaseResult:
        """Inject one fault; retried when the cycle passed the step before the signal landed."""
        rep = FaultCaseResult(case)
        for _ in range(attempts):
            rep = self._run_once(case)
            if rep.injected_in is not None:
                break
        return rep

    def _run_once(self, case: FaultCase) -> FaultCaseResult:
        rep = FaultCaseResult(case)
        plc, sig = self.plc, FAULTS[case.fault]
        plc.to_idle()
        plc.drain()
        ack = plc.command("start")
        if not ack.accepted:
            rep.problems.append(f"start refused: {ack.reason}")
            return rep
        target = f"Execute.{case.step}"
        st = plc.wait_for(
            lambda s: (s.state == "Execute" and s.step == case.step) or s.state in ("Complete", *SAFE_STATES),
            self.cycle_timeout,
        )
        if st is None or st.step != case.step:
            try:
                plc.results.get(timeout=self.cycle_timeout)
            except queue.Empty:
                pass  # reported below; the next attempt starts from whatever state the cell is in
            plc.wait_for(lambda s: s.state in ("Complete", *SAFE_STATES), 30)
            rep.problems.append(f"{target} not reached before the signal (cycle went on to {st and st.state})")
            return rep
        pid = self.workers.pid(case.role)
        t_sig_ns = time.time_ns()
        t_sig = time.monotonic()
        os.kill(pid, sig)
        rep.injected_in = target
        try:
            q_safe = self._observe(rep, t_sig_ns, t_sig)
        finally:
            if sig == signal.SIGSTOP:
                os.kill(pid, signal.SIGCONT)
        self._recover(rep, q_safe)
        return rep

    def _observe(self, rep: FaultCaseResult, t_sig_ns: int, t_sig: float) -> list[float] | None:
        """Detection, safe state, record, motion after detection; returns the arm's joints at rest.

        A fault in a worker the rest of the cycle does not use may be noticed only after the
        cycle completed (e.g. frozen during replanning, which ends sooner than one lease): the
        cycle's record is then rightly ``completed``, and the fault is noticed in Complete.
        """
        from cellctl.recording.replay import read_cycle

        plc, case = self.plc, rep.case
        bound = self.detect_bound_s[case.fault]
        rest = ("Complete", *SAFE_STATES)
        st = plc.wait_for(lambda s: s.state in rest, bound + self.cfg.supervisor.timeouts.stop + 10)
        if st is None:
            rep.problems.append(f"no safe state within {bound + 10:g} s (last status {plc.last_status})")
            return None
        rep.safe_state = st.state
        rep.safe_s = time.monotonic() - t_sig
        ev = self._events.first_after(t_sig_ns, case.role, timeout=max(0.0, bound + 0.5 - rep.safe_s))
        if ev is None:
            rep.problems.append(f"no event naming the {case.role} worker within {bound:g} s of the signal")
        else:
            t_det_ns, rep.detected_by = ev
            rep.detection_s = (t_det_ns - t_sig_ns) / 1e9
            if rep.detection_s > bound:
                rep.problems.append(f"detected after {rep.detection_s:.2f} s, beyond the bound of {bound:g} s")
        try:
            res = plc.results.get(timeout=10)
        except queue.Empty:
            rep.problems.append("no CycleResult for the cycle")
            return None
        rep.outcome, rep.reason = res.outcome.value, res.reason
        if st.state == "Complete":
            if rep.outcome not in self.good_outcomes:
                rep.problems.append(f"cycle completed as {rep.outcome!r}: {res.reason}")
        elif rep.outcome != "failed":
            rep.problems.append(f"partial cycle recorded as {rep.outcome!r}, expected 'failed'")
        elif case.role not in (res.reason or ""):
            rep.problems.append(f"the recorded reason does not name the {case.role} worker: {res.reason!r}")
        time.sleep(0.3)  # joints published at robot.joint_state_hz; let the last motion sample arrive
        # the arm at rest, asked from the robot itself (its published joints lag up to a period)
        q_safe = self._arm() if case.role != "robot" else None
        if not res.log:
            rep.problems.append("the cycle has no log")
            return q_safe
        if rep.detection_s is not None:
            rec = read_cycle(self.cfg.path(res.log))
            motion_topics = {topics.request(keys.robot_op(self.cfg.cell_id, op)) for op in MOTION_OPS}
            t_det_ns = t_sig_ns + int(rep.detection_s * 1e9)
            motion = [m for m in rec.messages if m.log_time > t_det_ns and m.topic in motion_topics]
            rep.motion_requests_after_detection = len(motion)
            if motion:
                rep.problems.append(f"{len(motion)} motion request(s) sent after the fault was detected")
        return q_safe

    def _arm(self) -> list[float] | None:
        """The robot's joints now, asked by a ``robot/state`` request (None if it does not answer)."""
        try:
            st, _ = request(
                self.plc.session,
                keys.robot_op(self.cfg.cell_id, "state"),
                RobotStateRequest(),
                RobotState,
                timeout=5,
                role="robot",
            )
        except CellError:
            return None
        return list(st.joints)

    def _recover(self, rep: FaultCaseResult, q_safe: list[float] | None) -> None:
        plc, case = self.plc, rep.case
        t0 = time.monotonic()
        if case.fault == "kill":
            self.workers.restart(case.role)
        roles = list(self.cfg.supervisor.required_workers)
        if not plc.wait_workers(roles, 120):
            rep.problems.append(f"workers not back within 120 s: {plc.last_status and plc.last_status.workers}")
            return
        # A robot that was frozen is compared with itself just after resuming (where it stood
        # when frozen cannot be asked; that it does not jump is tested at slow speed in
        # tests/workers/test_robot_safety.py); a killed one restarts at home.
        if case.role == "robot" and case.fault == "freeze":
            q_safe = self._arm()
        if q_safe is not None:
            time.sleep(0.5)
            q_now = self._arm()
            if q_now is not None:
                rep.robot_moved_rad = max(abs(a - b) for a, b in zip(q_safe, q_now, strict=True))
                if rep.robot_moved_rad > 1e-6:
                    rep.problems.append(f"the arm moved {rep.robot_moved_rad:.4f} rad after the safe state")
        try:
            plc.to_idle()
            res = plc.run_cycle(self.cycle_timeout)
        except CellError as err:
            rep.problems.append(f"recovery cycle: {err}")
            return
        rep.recovery_outcome = res.outcome.value
        rep.recovery_s = time.monotonic() - t0
        if res.outcome.value not in self.good_outcomes:
            rep.problems.append(f"recovery cycle ended {res.outcome.value}: {res.reason}")


class _ChildWorkers:
    """WorkerControl over the daemon's child workers (:class:`cellctl.app.WorkerProcesses`)."""

    def __init__(self, procs: Any) -> None:
        self.procs = procs

    def pid(self, role: str) -> int:
        return self.procs.procs[role].pid

    def restart(self, role: str) -> None:
        self.procs.procs[role].wait(10)  # reap the killed one
        self.procs.start_one(role)


BENCH_STEPS = ("approaching", "identifying", "checking_cache", "scanning")
"""Steps long enough on the sim to be hit from a Status (classifying/reporting last < 1 ms)."""


def bench_faults(opts: BenchOptions) -> dict[str, Any]:
    """Every worker × {kill, freeze} × step on the sim cell; detection times and recovery.

    ``opts.n`` (optional) keeps only the first n cases.
    """
    from cellctl.bench.reliability.sim_cell import FAST_SIM, running_sim_cell

    reports: list[FaultCaseResult] = []
    with running_sim_cell(opts, "faults", FAST_SIM) as run:
        cfg = run.cfg
        cases = [FaultCase(r, f, s) for r in cfg.supervisor.spawn_workers for f in FAULTS for s in BENCH_STEPS]
        cases = cases[: opts.n] if opts.n else cases
        inj = FaultInjector(cfg, run.plc, _ChildWorkers(run.cell.workers))
        try:
            for i, case in enumerate(cases, 1):
                rep = inj.run(case)
                reports.append(rep)
                det = f"{rep.detection_s:.3f} s" if rep.detection_s is not None else "-"
                print(
                    f"faults {i}/{len(cases)}: {case.name}: detected in {det}, {rep.safe_state}, "
                    f"recovery {rep.recovery_outcome} {'ok' if rep.ok else 'PROBLEMS: ' + '; '.join(rep.problems)}",
                    file=sys.stderr,
                )
        finally:
            inj.close()
    by_fault: dict[str, Any] = {}
    for f in FAULTS:
        ds = sorted(r.detection_s for r in reports if r.case.fault == f and r.detection_s is not None)
        if ds:
            by_fault[f] = {
                "n": len(ds),
                "min_s": round(ds[0], 3),
                "median_s": round(ds[len(ds) // 2], 3),
                "max_s": round(ds[-1], 3),
                "bound_s": inj.detect_bound_s[f],
            }
    return {
        "cases": len(reports),
        "ok": sum(r.ok for r in reports),
        "detection": by_fault,
        "table": [
            {
                "case": r.case.name,
                "detection_s": None if r.detection_s is None else round(r.detection_s, 3),
                "safe_state": r.safe_state,
                "motion_after": r.motion_requests_after_detection,
                "arm_moved_rad": r.robot_moved_rad,
                "recovery": r.recovery_outcome,
                "ok": r.ok,
            }
            for r in reports
        ],
        "reports": [r.as_dict() for r in reports],
        "config": {"lease_ms": cfg.bus.lease_ms, "on_worker_lost": cfg.supervisor.on_worker_lost},
        "out": str(run.out),
    }
