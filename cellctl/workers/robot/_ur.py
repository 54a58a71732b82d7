"""The UR10e backend: ur-rtde (``rtde_control``, ``rtde_receive``, ``dashboard_client``).

Execution: the planned path, timed by :mod:`cellctl.motion`, goes to the controller as **one
asynchronous** ``moveJ(path)`` with blend radius 0, not as ``servoJ`` streaming. Why: the
controller then runs the trajectory in its own 500 Hz loop — a Python worker on a loaded
machine cannot hold a 2–8 ms servo deadline, and a missed deadline is a jerk or a protective
stop on a real arm; blend 0 keeps the arm on the collision-checked straight segments (the
motion module's profile per segment is the controller's ``movej`` profile: same leading-axis
speed and acceleration), and the asynchronous call leaves the worker free to watch safety,
the supervisor's token and its own stalls while the arm moves, and to ``stopJ`` at any moment.

Safety: a monitor thread polls the RTDE state at ``robot.ur.faults.monitor_hz`` (100 Hz: ≤ 10 ms
plus the 8 ms RTDE period to notice) and latches a **fault** on protective stop, emergency
stop, safeguard stop, reduced mode, a robot mode other than RUNNING, a lost or stale RTDE
connection, or the control program stopping during a motion. A fault stops the motion
(``stopJ``), refuses further motions and is only cleared by an explicit maintenance command.
The controller's RTDE watchdog (``setWatchdog``) stops the program if this worker stops
kicking it (a frozen worker, a dropped link), so a motion never outlives its worker.

ur-rtde's interfaces are not thread-safe: every call goes through :attr:`UrRobot.io` (one lock).
A call that *sends* on the control interface (``moveJ``, ``stopJ``, ``kickWatchdog``, …) can block
for good once its link died (ur-rtde then reconnects inside the call), so those run on a call
thread of their own and are waited for with a bound; one that overruns marks that interface
*wedged*: it is abandoned (disconnected on a throw-away thread), never called again, and the
operator's ``clear_fault`` connects fresh interfaces. Reads are cache reads and never block.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from cellctl.config import CellConfig
from cellctl.errors import RobotError
from cellctl.geometry import robot_model as rm
from cellctl.geometry.catalog import Catalog
from cellctl.messages import (
    ApproachReply,
    ApproachRequest,
    FaultCondition,
    FaultReport,
    MoveReply,
    MoveRequest,
    RobotMaintenanceReply,
    RobotMaintenanceRequest,
    RobotState,
    WashReply,
    WashRequest,
)
from cellctl.workers.robot._planned import PlannedRobot, TwinBaseReport

__all__ = ["UrRobot", "classify_fault", "path_deviation"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

_ROBOT_MODES = {
    -1: "NO_CONTROLLER",
    0: "DISCONNECTED",
    1: "CONFIRM_SAFETY",
    2: "BOOTING",
    3: "POWER_OFF",
    4: "POWER_ON",
    5: "IDLE",
    6: "BACKDRIVE",
    7: "RUNNING",
    8: "UPDATING_FIRMWARE",
}
_RUNNING = 7
_PLAYING = 2
_FAULT_BITS = (  # safety_status_bits (RTDE guide), most severe first
    ((1 << 5) | (1 << 6) | (1 << 7), "emergency stop"),
    (1 << 9, "safety fault"),
    (1 << 8, "safety violation"),
    (1 << 2, "protective stop"),
    (1 << 4, "safeguard stop"),
)
_REDUCED = 1 << 1
_SAFETY_MODES = {
    1: "NORMAL",
    2: "REDUCED",
    3: "PROTECTIVE_STOP",
    4: "RECOVERY",
    5: "SAFEGUARD_STOP",
    6: "SYSTEM_EMERGENCY_STOP",
    7: "ROBOT_EMERGENCY_STOP",
    8: "VIOLATION",
    9: "FAULT",
    10: "VALIDATE_JOINT_ID",
    11: "UNDEFINED_SAFETY_MODE",
    12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
    13: "SYSTEM_THREE_POSITION_ENABLING_STOP",
}
_SAFETY_FLAGS = (  # safety_status_bits, bit -> name (RTDE guide)
    (0, "normal_mode"),
    (1, "reduced_mode"),
    (2, "protective_stopped"),
    (3, "recovery_mode"),
    (4, "safeguard_stopped"),
    (5, "system_emergency_stopped"),
    (6, "robot_emergency_stopped"),
    (7, "emergency_stopped"),
    (8, "violation"),
    (9, "fault"),
    (10, "stopped_due_to_safety"),
)
_CONDITIONS: dict[str, FaultCondition] = {
    "emergency stop": "emergency_stop",
    "safety fault": "safety_fault",
    "safety violation": "safety_violation",
    "protective stop": "protective_stop",
    "safeguard stop": "safeguard_stop",
    "reduced mode": "reduced_mode",
}
_RTDE_VARIABLES = [
    "timestamp",
    "actual_q",
    "actual_TCP_pose",
    "robot_mode",
    "safety_mode",
    "safety_status_bits",
    "runtime_state",
    "speed_scaling",
    "target_speed_fraction",
]


def classify_fault(safety_bits: int, robot_mode: int, reduced_is_fault: bool) -> str | None:
    """The fault a safety word and robot mode mean, or None when the arm may move."""
    for mask, name in _FAULT_BITS:
        if safety_bits & mask:
            return name
    if reduced_is_fault and safety_bits & _REDUCED:
        return "reduced mode"
    if robot_mode != _RUNNING:
        return f"robot mode {_ROBOT_MODES.get(robot_mode, robot_mode)} (not RUNNING)"
    return None


def _condition_of(name: str) -> FaultCondition:
    """The typed condition of a :func:`classify_fault` name."""
    return _CONDITIONS.get(name, "robot_mode")


def path_deviation(path: NDArray[np.float64], q: NDArray[np.float64]) -> float:
    """Largest joint deviation (rad) of ``q`` from the nearest point of the piecewise-linear ``path``."""
    best = float(np.abs(q - path[0]).max())
    for a, b in zip(path[:-1], path[1:], strict=True):
        d = b - a
        den = float(d @ d)
        s = 0.0 if den == 0 else float(np.clip((q - a) @ d / den, 0.0, 1.0))
        best = min(best, float(np.abs(q - (a + s * d)).max()))
    return best


class _Wedged(RuntimeError):
    """A control call overran its bound: the interface is given up (a RuntimeError like ur-rtde's)."""


class _Late(RuntimeError):
    """A call that may overrun (a watchdog kick on a loaded machine) did: nothing is given up."""


class _CallThread:
    """Runs one interface's sending calls in order on a daemon thread; each caller waits with a bound.

    Daemon, not a ``ThreadPoolExecutor``: a call stuck in ur-rtde must not hold up the worker's exit.
    """

    def __init__(self, name: str) -> None:
        self.wedged: str | None = None
        self.busy = False
        """A call is queued or running (a late one that was not fatal may still be)."""
        self.closed = False
        """Its interface is given up or replaced: calls still queued are dropped, not run."""
        self._q: queue.SimpleQueue[tuple[Callable[..., Any], tuple[Any, ...], threading.Event, list[Any]] | None]
        self._q = queue.SimpleQueue()
        threading.Thread(target=self._run, name=name, daemon=True).start()

    def _run(self) -> None:
        while (item := self._q.get()) is not None:
            fn, args, done, box = item
            if self.closed:
                # a call queued behind one that wedged (or behind the interface's replacement) must not
                # run later on the old interface: ur-rtde would reconnect it inside the call and restart
                # the control program under the fresh interface's motion
                box.append((False, _Wedged(f"{getattr(fn, '__name__', 'call')} dropped: the interface was given up")))
                done.set()
                continue
            try:
                box.append((True, fn(*args)))
            except Exception as err:  # handed to the caller
                box.append((False, err))
            self.busy = False
            done.set()

    def call(self, timeout_s: float, fn: Callable[..., Any], *args: Any, fatal: bool = True) -> Any:
        """``fn(*args)`` on the call thread, waited for ``timeout_s``.

        Raises:
            _Wedged: the interface was given up, or (``fatal``) this call overran: it is given up now.
            _Late: a call that is not ``fatal`` overran (it may still finish; nothing is given up).
        """
        if self.wedged is not None or self.closed:
            raise _Wedged(self.wedged or "the interface was replaced")
        done: threading.Event = threading.Event()
        box: list[Any] = []
        self.busy = True
        self._q.put((fn, args, done, box))
        if not done.wait(timeout_s):
            late = f"{getattr(fn, '__name__', 'call')} did not return within {timeout_s:g} s"
            if not fatal:
                raise _Late(late)
            self.wedged = late
            self.close()
            raise _Wedged(self.wedged)
        ok, value = box[0]
        if ok:
            return value
        raise value

    def close(self) -> None:
        self.closed = True
        self._q.put(None)


_T_KICK = 1.0
_T_CMD = 5.0
_T_PATH = 15.0
"""Bounds (s) of control calls: a watchdog kick, a stop/setting, a path (stop, upload, start, command).
Generous: a dead link is noticed by the receive side (disconnected, or no data for data_stale_ms); the
bounds only keep a wedged call from holding the lock, and a 0.5 s kick bound overran under a load
average of 10 on 2 cores (the demo's only false fault)."""


def _dispose(*handles: Any) -> None:
    """Disconnect given-up interfaces on a throw-away thread (a wedged one may block in there)."""

    def run() -> None:
        for h in handles:
            if h is not None:
                try:
                    h.disconnect()
                except RuntimeError:
                    pass

    t = threading.Thread(target=run, name="ur-dispose", daemon=True)
    t.start()
    t.join(2.0)


class UrRobot(TwinBaseReport, PlannedRobot):
    """The ``ur`` backend of the robot role.

    Args:
        cfg: cell config (``robot.ur`` for the controller; ``sim`` for the cell layout).
        catalog: an already loaded catalog.
        on_change: called after the joints or the scenario changed.
        on_fault: called with the :class:`~cellctl.messages.FaultReport` of a fault when one is
            latched (``active``), and when the operator cleared it (not ``active``); the worker
            publishes it and withdraws/redeclares its liveliness token.

    Raises:
        RobotError: the controller is unreachable, not a UR10e, in local control, not RUNNING
            (the mode is named), safety-stopped, or refuses ur-rtde's recipes.
    """

    def __init__(
        self,
        cfg: CellConfig,
        catalog: Catalog | None = None,
        on_change: Callable[[], None] | None = None,
        on_fault: Callable[[FaultReport], None] | None = None,
    ) -> None:
        self.io = threading.Lock()
        """The one lock around every ur-rtde call (its interfaces are not thread-safe)."""
        self.ur = cfg.robot.ur
        self.on_fault = on_fault
        self._c: Any = None
        self._r: Any = None
        self._d: Any = None
        self._calls = _CallThread("ur-control-calls")
        self._fault: str | None = None
        self.fault_report: FaultReport | None = None
        """The latched fault, typed (condition, robot and safety mode, safety bits), until cleared."""
        self._last_state: dict[str, Any] | None = None
        self._motion_seq = 0
        """Counts motions sent: a stop meant for one motion never reaches a later one."""
        self._fault_motion = -1
        """The motion the latched fault's stopJ is for."""
        self._q_meas: NDArray[np.float64] | None = None
        self._tcp: NDArray[np.float64] | None = None
        self._ts = -1.0
        self._data_t = time.monotonic()
        self._runtime = 0
        self.speed_slider: float | None = None
        self.tracking: deque[float] = deque(maxlen=100_000)
        """Path deviation (rad) of every sample during motions (``cellctl bench ur``)."""
        self.fault_log: list[tuple[float, str]] = []
        """(monotonic time, text) of every latched fault."""
        super().__init__(cfg, catalog, on_change)
        self._connect()
        self._monitor_stop = threading.Event()
        self._monitor = threading.Thread(target=self._watch, name="ur-safety-monitor", daemon=True)
        self._monitor.start()
        self._kicker = threading.Thread(target=self._kick_loop, name="ur-watchdog-kick", daemon=True)
        self._kicker.start()

    def _accel_fraction(self) -> float:
        return self.ur.accel_fraction

    @property
    def publishes_twin(self) -> bool:
        """Against the emulator, this worker publishes the twin's SimState with the arm's RTDE joints."""
        return self.ur.twin

    # --- connection -------------------------------------------------------------------------

    def _connect(self) -> None:
        """Connect with doubling back-off; refusals that retrying cannot fix raise at once."""
        delay = 0.25
        last: Exception | None = None
        for attempt in range(self.ur.connect_attempts):
            try:
                self._connect_once()
                return
            except _Refused as err:
                self._disconnect()
                raise RobotError(str(err)) from None
            except RuntimeError as err:  # ur-rtde: socket errors, timeouts
                self._disconnect()
                last = err
                log.warning("UR connect attempt %d failed: %s", attempt + 1, err)
                time.sleep(delay)
                delay *= 2
        raise RobotError(
            f"cannot connect to the UR controller at {self.ur.host} after {self.ur.connect_attempts} attempts: {last}"
        )

    def _connect_once(self) -> None:
        import dashboard_client
        import rtde_control
        import rtde_receive

        host = self.ur.host
        with self.io:
            d = dashboard_client.DashboardClient(host)
            d.connect()
            self._d = d
            version = d.polyscopeVersion()
            model = d.getRobotModel().strip()
            major = int(version.split(".")[0]) if version[:1].isdigit() else 0
            name = f"{model}e" if major >= 5 and not model.endswith("e") else model
            if name != self.ur.expected_model:
                raise _Refused(
                    f"wrong robot model: the dashboard reports {model!r} (PolyScope {version}, i.e. {name}); "
                    f"robot.ur.expected_model is {self.ur.expected_model!r}"
                )
            if self.ur.expected_serial is not None:
                serial = d.getSerialNumber().strip()
                if serial != self.ur.expected_serial:
                    raise _Refused(
                        f"wrong robot: serial number {serial!r}, "
                        f"robot.ur.expected_serial is {self.ur.expected_serial!r}"
                    )
            if not d.isInRemoteControl():
                raise _Refused("the robot is in local control mode: switch the pendant to remote control")
            mode = d.robotmode().split(":")[-1].strip()
            if mode != "RUNNING":
                raise _Refused(
                    f"the robot is not in RUNNING mode (robot mode {mode}); power it on and release the brakes "
                    "(maintenance actions power_on, brake_release)"
                )
            safety = d.safetystatus().split(":")[-1].strip()
            if safety not in ("NORMAL", "REDUCED"):
                raise _Refused(f"the robot's safety status is {safety}; clear it on the pendant or by maintenance")
            try:
                self._r = rtde_receive.RTDEReceiveInterface(host, 125.0, _RTDE_VARIABLES)
                self._c = rtde_control.RTDEControlInterface(host)
                self._calls.close()
                self._calls = _CallThread("ur-control-calls")
                self._send(_T_CMD, self._c.setWatchdog, self.ur.faults.watchdog_hz)
            except RuntimeError as err:
                if "already in use" in str(err) or "not found" in str(err).lower():
                    raise _Refused(f"the controller refused ur-rtde's RTDE recipe: {err}") from None
                raise
            self._read_state()
        log.info("connected to %s at %s (PolyScope %s)", name, host, version)
        self._check_tcp()

    def _send(self, timeout_s: float, fn: Callable[..., Any], *args: Any, fatal: bool = True) -> Any:
        """A sending control call, bounded (caller holds :attr:`io`); an overrun gives the interface up
        (unless not ``fatal``: then :class:`_Late`).

        Raises:
            RuntimeError: ur-rtde's error, :class:`_Wedged` (overrun, or given up before) or :class:`_Late`.
        """
        t0 = time.monotonic()
        try:
            return self._calls.call(timeout_s, fn, *args, fatal=fatal)
        except _Wedged:
            c, self._c = self._c, None
            if c is not None:
                log.error("UR control interface given up: %s", self._calls.wedged)
                threading.Thread(target=_dispose, args=(c,), name="ur-dispose", daemon=True).start()
            raise
        finally:
            dt = time.monotonic() - t0
            if dt > 0.25:
                log.info("UR %s took %.2f s", getattr(fn, "__name__", "call"), dt)

    def _linked(self) -> bool:
        """The control interface is there, not given up, and its link is up (cache reads)."""
        return self._c is not None and self._calls.wedged is None and bool(self._c.isConnected())

    def _disconnect(self) -> None:
        with self.io:
            handles, self._c, self._r, self._d = (self._c, self._r, self._d), None, None, None
            self._calls.close()
        _dispose(*handles)

    def close(self) -> None:
        if hasattr(self, "_monitor_stop"):
            self._monitor_stop.set()
            self._monitor.join(timeout=1.0)
            self._kicker.join(timeout=1.0)
        self._stopj()
        with self.io:
            if self._linked():
                try:
                    self._send(_T_CMD, self._c.stopScript)  # a clean end, not a watchdog expiry
                except RuntimeError:
                    pass
        self._disconnect()
        super().close()

    # --- state ------------------------------------------------------------------------------

    def _read_state(self, r: Any = None) -> dict[str, Any]:
        """One poll of the RTDE state of ``r`` (default: the current receive interface).

        The receive interface's getters are cache reads under its own mutex: the monitor polls
        without :attr:`io`, so a control call that blocks (a stalled controller holds ``moveJ``)
        cannot hide the stall from it.
        """
        r = self._r if r is None else r
        st = {
            "connected": bool(r.isConnected()),
            "ts": float(r.getTimestamp()),
            "q": np.array(r.getActualQ(), dtype=np.float64),
            "tcp": np.array(r.getActualTCPPose(), dtype=np.float64),
            "bits": int(r.getSafetyStatusBits()),
            "mode": int(r.getRobotMode()),
            "safety_mode": int(r.getSafetyMode()),
            "runtime": int(r.getRuntimeState()),
            "slider": float(r.getTargetSpeedFraction()),
        }
        if st["q"].shape == (6,):
            self._q_meas = st["q"]
            self._tcp = st["tcp"]
        self._runtime = st["runtime"]
        self.speed_slider = st["slider"]
        self._last_state = st
        return st

    def _joints_now(self) -> NDArray[np.float64]:
        """The joints as the receive interface holds them now (a cache read; no :attr:`io`)."""
        r = self._r
        if r is not None:
            try:
                self._read_state(r)
            except RuntimeError:  # a lost link: the monitor names it; the last sample stands
                pass
        return self._read_joints()

    def _read_joints(self) -> NDArray[np.float64]:
        q = self._q_meas
        return (q if q is not None else super()._read_joints()).copy()

    def state(self) -> RobotState:
        st = super().state()
        return st.model_copy(update={"speed_slider": self.speed_slider, "fault": self._fault})

    def _check_tcp(self) -> None:
        q, tcp = self._q_meas, self._tcp
        if q is None or tcp is None or tcp.shape != (6,):
            return
        T = rm.fk(q)
        dp = float(np.linalg.norm(T[:3, 3] - tcp[:3]))
        R = Rotation.from_rotvec(tcp[3:]).as_matrix()
        dr = float(np.degrees(Rotation.from_matrix(T[:3, :3].T @ R).magnitude()))
        if dp > self.ur.tcp_warn_m:
            log.warning(
                "robot TCP differs from the cell's robot model by %.1f mm, %.2f deg (> %.1f mm): wrong model, "
                "TCP offset or calibration? Flange/camera poses come from the model.",
                dp * 1e3,
                dr,
                self.ur.tcp_warn_m * 1e3,
            )
        self.tcp_error_m = dp

    tcp_error_m: float = 0.0
    """Robot TCP vs the model's FK at the last check (m)."""

    # --- safety monitor ---------------------------------------------------------------------

    @property
    def fault(self) -> str | None:
        return self._fault

    def _watch(self) -> None:
        """The safety monitor: reads the RTDE state (cache reads, never a control call, so nothing
        it waits for can delay it) and latches the first fault it sees."""
        period = 1.0 / self.ur.faults.monitor_hz
        stale = self.ur.faults.data_stale_ms / 1e3
        not_playing_since: float | None = None
        while not self._monitor_stop.wait(period):
            found: tuple[FaultCondition, str] | None = None
            r = self._r
            if r is None:
                continue
            st: dict[str, Any] | None
            try:
                st = self._read_state(r)
            except RuntimeError as err:
                st, found = None, ("lost_connection", f"lost RTDE connection to {self.ur.host}: {err}")
            if self._calls.wedged is not None and self._c is None and found is None:
                found = ("stall", f"lost RTDE connection to {self.ur.host}: the control interface stopped answering "
                         f"({self._calls.wedged})")  # fmt: skip
            now = time.monotonic()
            if st is not None and found is None:
                if st["ts"] != self._ts:
                    self._ts, self._data_t = st["ts"], now
                if not st["connected"]:
                    found = ("lost_connection", f"lost RTDE connection to {self.ur.host}")
                elif now - self._data_t > stale:
                    found = ("stall", f"no RTDE data for {1e3 * (now - self._data_t):.0f} ms "
                             "(controller stalled or link lost)")  # fmt: skip
                else:
                    name = classify_fault(st["bits"], st["mode"], self.ur.faults.reduced_mode)
                    if name is not None:
                        found = (_condition_of(name), name)
                    # this connection's samples may still show the program restart moveJ(path) does:
                    # only a stop that lasts beyond a few RTDE periods is one
                    if not (self._moving and st["runtime"] != _PLAYING):
                        not_playing_since = None
                    elif not_playing_since is None:
                        not_playing_since = now
                    elif found is None and now - not_playing_since > 0.05:
                        found = ("program_stopped", "the control program stopped during a motion (RTDE watchdog or "
                                 "controller)")  # fmt: skip
            if found is not None and self._fault is None:
                self._latch(found[1], found[0])
            if st is not None and self._moving:
                self._changed()

    def _kick_loop(self) -> None:
        """Kick the controller's RTDE watchdog while the control program runs.

        Its own thread, not the safety monitor's: a kick waits for the control script's ready
        state (for as long as a stalled controller stalls), and the monitor must keep looking
        meanwhile. Only when :attr:`io` is free: a control call holding it (a path being sent)
        restarts the program, and with it the watchdog.
        """
        period = 1.0 / min(max(10.0 * self.ur.faults.watchdog_hz, 10.0), self.ur.faults.monitor_hz)
        while not self._monitor_stop.wait(period):
            if self._runtime != _PLAYING or not self.io.acquire(timeout=period):
                continue
            try:
                if self._linked() and not self._calls.busy:
                    self._send(_T_KICK, self._c.kickWatchdog, fatal=False)
            except _Late as err:
                log.warning("UR watchdog kick late: %s", err)
            except RuntimeError as err:  # _Wedged: the monitor names it (the interface is given up)
                log.warning("UR watchdog kick failed: %s", err)
            finally:
                self.io.release()

    def _latch(self, reason: str, condition: FaultCondition) -> None:
        self._fault = reason
        self.fault_report = self._report(condition, reason, active=True)
        self.fault_log.append((time.monotonic(), reason))
        log.error("UR fault: %s", reason)
        self.stop(f"UR fault: {reason}")
        # stopJ first, but the report does not wait for it: behind a control call that a stalled
        # controller holds it waits for the stall to end, and on a loaded machine its round trip alone
        # took most of the 100 ms the supervisor has to reach its safe state (the stopJ follows as soon
        # as the lock is free, and only if no later motion began meanwhile)
        self._fault_motion = self._motion_seq
        t = threading.Thread(target=self._stopj, args=(self._fault_motion,), name="ur-fault-stopj", daemon=True)
        t.start()
        t.join(0.01)
        if self.on_fault is not None:
            try:
                self.on_fault(self.fault_report)
            except Exception:
                log.exception("on_fault callback failed")

    def _report(self, condition: FaultCondition, detail: str, active: bool) -> FaultReport:
        """The typed report of a fault, with the controller's last known modes and safety bits."""
        st = self._last_state
        if st is None:
            return FaultReport(role="robot", active=active, condition=condition, detail=detail)
        bits = int(st["bits"])
        return FaultReport(
            role="robot",
            active=active,
            condition=condition,
            detail=detail,
            robot_mode=_ROBOT_MODES.get(int(st["mode"]), str(st["mode"])),
            safety_mode=_SAFETY_MODES.get(int(st["safety_mode"]), str(st["safety_mode"])),
            safety_status_bits=bits,
            safety_flags=[name for bit, name in _SAFETY_FLAGS if bits & (1 << bit)],
        )

    def _reupload(self) -> None:
        """Send the control program again and wait until it runs (caller holds :attr:`io`).

        ur-rtde's ``reuploadScript`` returns once the script is sent, before the program starts.
        """
        if not self._send(_T_PATH, self._c.reuploadScript):
            raise RobotError(f"could not send the control program to {self.ur.host}")
        deadline = time.monotonic() + 10.0  # a real controller: ≈ 0.1 s; a loaded shared machine: seconds
        while not self._c.isProgramRunning():
            if time.monotonic() > deadline:
                raise RobotError("the control program did not start within 10 s (robot mode, safety or local control?)")
            time.sleep(0.005)
        self._send(_T_CMD, self._c.setWatchdog, self.ur.faults.watchdog_hz)

    def _stopj(self, motion: int | None = None) -> None:
        """stopJ, unless the link is down (then the controller's RTDE watchdog stops the arm).

        ``motion``: the motion (:attr:`_motion_seq`) this stop is for; a stop that only got the lock
        after a later motion began is dropped (it would stop the operator's next, good motion).
        """
        with self.io:
            if motion is not None and motion != self._motion_seq:
                log.debug("stopJ for motion %d dropped: motion %d began since", motion, self._motion_seq)
                return
            if self._linked():
                try:
                    self._send(_T_CMD, self._c.stopJ, self.ur.stop_decel, False)
                except RuntimeError as err:
                    log.warning("stopJ failed: %s", err)

    def stop(self, reason: str) -> None:
        super().stop(reason)
        if self._moving and not reason.startswith("UR fault"):
            # the supervisor-token rule: stop the arm now, not when the motion loop next looks
            threading.Thread(target=self._stopj, args=(self._motion_seq,), name="ur-stopj", daemon=True).start()

    # --- motion -----------------------------------------------------------------------------

    def approach(self, req: ApproachRequest) -> ApproachReply:
        self._refuse_if_faulted("approach")  # at once, not after planning under the motion lock
        return super().approach(req)

    def move(self, req: MoveRequest) -> MoveReply:
        # at once: planning first held the motion lock for seconds while faulted, and a scenario change
        # (the next bin) sent meanwhile was refused "busy" (the UR demo's end after a fault)
        self._refuse_if_faulted("move")
        return super().move(req)

    def wash(self, req: WashRequest) -> WashReply:
        self._refuse_if_faulted("wash")
        return super().wash(req)

    def _refuse_if_faulted(self, what: str) -> None:
        if self._fault is not None:
            raise RobotError(
                f"cannot {what}: UR fault active ({self._fault}); an operator must clear it "
                "(maintenance: unlock_protective_stop / power_on / brake_release, then clear_fault)"
            )
        if not self._linked():
            raise RobotError(f"cannot {what}: not connected to the UR controller at {self.ur.host}")

    def _execute(self, path: NDArray[np.float64]) -> float:
        self._refuse_if_faulted("move")
        traj = self.trajectory(path)
        entries = traj.movej_path()
        q0 = self.joints
        if float(np.abs(q0 - path[0]).max()) > self.ur.joint_tolerance_rad * 5:
            raise RobotError(
                f"the arm is at {np.round(q0, 4).tolist()}, not where the path starts "
                f"({np.round(path[0], 4).tolist()}); refusing to move"
            )
        if not entries:
            return 0.0
        try:
            with self.io:
                self._motion_seq += 1
                motion = self._motion_seq
                if not self._c.isProgramRunning():
                    self._reupload()  # e.g. the watchdog stopped it while the worker was idle
                ok = self._send(_T_PATH, self._c.moveJ, entries, True)
                if ok:  # moveJ(path) restarted the program: its watchdog with it
                    self._send(_T_CMD, self._c.setWatchdog, self.ur.faults.watchdog_hz)
                log.debug("motion %d sent (%d entries, %.2f s): %s", motion, len(entries), traj.duration, ok)
        except _Wedged as err:
            if self._fault is None:
                self._latch(
                    f"lost RTDE connection to {self.ur.host}: the control interface stopped answering ({err})", "stall"
                )
            raise RobotError(f"motion not started: UR fault ({self._fault})") from None
        except RuntimeError as err:
            raise RobotError(f"the UR controller refused the motion: {err}") from None
        if not ok:
            raise RobotError(f"the UR controller refused the motion ({self._fault or 'program not ready'})")
        t0 = time.monotonic()
        last = t0
        self._moving = True
        period = 1.0 / self.ur.faults.monitor_hz
        slow = max(self.speed_slider or 1.0, 0.05)
        try:
            while True:
                time.sleep(period)
                now = time.monotonic()
                self._check_not_frozen(max(now - last, now - self._tick), "motion")
                if self._fault is not None:
                    raise RobotError(f"motion aborted: UR fault ({self._fault}) at {np.round(self.joints, 4).tolist()}")
                if self._stop.is_set():
                    raise RobotError(
                        f"motion stopped ({self._stop_reason or 'stop requested'}) "
                        f"at {np.round(self.joints, 4).tolist()}"
                    )
                with self.io:
                    c = self._c
                    if c is None:  # given up by the monitor: the fault is latched, seen next round
                        last = time.monotonic()
                        continue
                    running = bool(c.getAsyncOperationProgressEx().isAsyncOperationRunning())
                # after the lock: waiting for it behind a watchdog kick (bounded, 1 s) is no freeze, the
                # monitor thread watched the controller meanwhile (a false "frozen" after a stall's recovery)
                last = time.monotonic()
                q = self.joints
                self.tracking.append(path_deviation(path, q))
                if not running:
                    # "finished" comes on the control interface (500 Hz); the joints the monitor last
                    # polled from the receive interface (125 Hz) can be tens of ms older under load, i.e.
                    # a few mrad before the goal: judge the end on joints read now, and again while
                    # waiting, not on that sample (the false "ended short" after a stall's recovery)
                    polled = float(np.abs(q - path[-1]).max())
                    q = self._joints_now()
                    err = float(np.abs(q - path[-1]).max())
                    if err <= self.ur.joint_tolerance_rad:
                        if polled > self.ur.joint_tolerance_rad:
                            log.info("motion %d: 'finished' before the polled joints (%.4f rad off)", motion, polled)
                        self._check_tcp()
                        return now - t0
                    if now - t0 > 0.5:
                        # a safety stop ends the program in the same sample the monitor reads its bits
                        # from: give it a few polls to latch, so the error names the fault
                        deadline = now + max(15 * period, 0.3)
                        while self._fault is None and time.monotonic() < deadline:
                            time.sleep(period)
                            q = self._joints_now()
                            if float(np.abs(q - path[-1]).max()) <= self.ur.joint_tolerance_rad and self._fault is None:
                                log.info(
                                    "motion %d: 'finished' came %.0f ms before joints at the goal (%.4f rad off)",
                                    motion, 1e3 * (time.monotonic() - now), err,
                                )  # fmt: skip
                                self._check_tcp()
                                return now - t0
                            err = float(np.abs(q - path[-1]).max())
                        if self._fault is not None:
                            raise RobotError(f"motion aborted: UR fault ({self._fault}) at {np.round(q, 4).tolist()}")
                        raise RobotError(f"the motion ended {err:.4f} rad short of its goal (stopped)")
                if now - t0 > traj.duration / slow + 5.0:
                    raise RobotError(f"the motion did not finish within {traj.duration / slow + 5.0:.1f} s")
        except RobotError as err:
            log.debug("motion %d failed: %s", motion, err)
            if self._fault is None or self._fault_motion != motion:  # else the latch's stopJ is this motion's
                self._stopj(motion)  # never leave an arm moving behind a failed motion
            raise
        finally:
            self._moving = False
            self._changed()

    # --- maintenance (an operator's explicit commands) ----------------------------------------

    def maintenance(self, req: RobotMaintenanceRequest) -> RobotMaintenanceReply:
        """Run one maintenance action; ``clear_fault`` only when the robot is healthy again.

        Raises:
            RobotError: the controller refused the action, or (clear_fault) what is still wrong.
        """
        log.warning("maintenance %s by %s", req.action, req.user)
        if req.action == "clear_fault":
            return self._clear_fault(req)
        with self.io:
            if self._d is None:
                raise RobotError(f"not connected to the UR dashboard at {self.ur.host}")
            try:
                if req.action == "unlock_protective_stop":
                    self._d.unlockProtectiveStop()
                    detail = "Protective stop releasing"
                elif req.action == "close_safety_popup":
                    self._d.closeSafetyPopup()
                    detail = "closing safety popup"
                elif req.action == "power_on":
                    self._d.powerOn()
                    detail = "Powering on"
                else:
                    self._d.brakeRelease()
                    detail = "Brake releasing"
            except (RuntimeError, ValueError) as err:  # ur-rtde raises logic_error → RuntimeError
                raise RobotError(f"the UR dashboard refused {req.action}: {err}") from None
        return RobotMaintenanceReply(action=req.action, detail=detail, fault=self._fault)

    def _clear_fault(self, req: RobotMaintenanceRequest) -> RobotMaintenanceReply:
        # the motion the fault interrupted must have ended (its loop and its stopJ) before the fault
        # goes: a loop still running would read the cleared fault as "no fault", and its late stopJ
        # would land in the operator's next motion. Held throughout: no motion starts mid-clear.
        if not self._busy.acquire(timeout=_T_CMD + _T_PATH):
            raise RobotError("cannot clear the fault yet: the interrupted motion is still being stopped; try again")
        try:
            return self._clear_fault_idle(req)
        finally:
            self._busy.release()

    def _clear_fault_idle(self, req: RobotMaintenanceRequest) -> RobotMaintenanceReply:
        with self.io:
            reconnect = not self._linked() or self._r is None
            if not reconnect:
                try:
                    st = self._read_state()
                    reconnect = not st["connected"] or time.monotonic() - self._data_t > 0.5
                except RuntimeError:
                    reconnect = True
        if reconnect:  # after a drop or a stall: fresh interfaces, never the old ones again
            self._disconnect()
            self._connect()  # raises naming what is wrong (mode, safety, link)
            self._ts, self._data_t = -1.0, time.monotonic()
        deadline = time.monotonic() + 1.0  # the dashboard acts before the next RTDE sample shows it
        while True:
            with self.io:
                st = self._read_state()
            still = classify_fault(st["bits"], st["mode"], self.ur.faults.reduced_mode)
            if still is None:
                break
            if time.monotonic() > deadline:
                raise RobotError(f"cannot clear the fault: {still} is still active")
            time.sleep(0.02)
        with self.io:
            try:
                if self._c.isProgramRunning():
                    self._send(_T_CMD, self._c.setWatchdog, self.ur.faults.watchdog_hz)
                else:
                    self._reupload()
            except RuntimeError as err:
                raise RobotError(f"cannot clear the fault: the control program does not answer ({err})") from None
            self._data_t = time.monotonic()
        was, self._fault = self._fault, None
        report, self.fault_report = self.fault_report, None
        self._stop.clear()
        log.info("UR fault cleared by %s (%s)", req.user, was or "no fault")
        if self.on_fault is not None and report is not None:
            self.on_fault(report.model_copy(update={"active": False, "detail": f"cleared by maintenance ({was})"}))
        return RobotMaintenanceReply(action=req.action, detail=f"cleared ({was or 'no fault'})", fault=None)


class _Refused(Exception):
    """A connection refusal that retrying will not fix (wrong model, mode, local control)."""
