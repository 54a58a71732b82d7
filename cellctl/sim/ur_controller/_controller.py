"""The emulated UR10e controller: arm state, safety, the control script's register handshake.

One :meth:`UrController.tick` per 2 ms (500 Hz, the e-Series RTDE rate) advances the arm along
the commanded motion and then runs one iteration of the ``rtde_control`` script's main loop as
ur_rtde's published script does it: read ``input_int_register_0`` (the command code), act, and
answer in ``output_int_register_0`` (1 ready, 2 done with command); async progress in
``output_int_register_2`` (≥ 0 running, negative finished). The script text itself is not
interpreted — only its path injection (``movej([...],a=,v=,r=)`` lines) and register offsets.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from cellctl.geometry import robot_model as rm
from cellctl.motion import UR10E, UR10E_JOINT_ACCEL_CEILING, JointLimits, Trajectory, time_parametrize

__all__ = ["RobotMode", "RuntimeState", "SafetyMode", "UrController", "UrIdentity"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


class RobotMode(IntEnum):
    NO_CONTROLLER = -1
    DISCONNECTED = 0
    CONFIRM_SAFETY = 1
    BOOTING = 2
    POWER_OFF = 3
    POWER_ON = 4
    IDLE = 5
    BACKDRIVE = 6
    RUNNING = 7


class SafetyMode(IntEnum):
    NORMAL = 1
    REDUCED = 2
    PROTECTIVE_STOP = 3
    RECOVERY = 4
    SAFEGUARD_STOP = 5
    SYSTEM_EMERGENCY_STOP = 6
    ROBOT_EMERGENCY_STOP = 7
    VIOLATION = 8
    FAULT = 9


class RuntimeState(IntEnum):
    STOPPING = 0
    STOPPED = 1
    PLAYING = 2
    PAUSING = 3
    PAUSED = 4
    RESUMING = 5


# safety_status_bits (RTDE guide)
_SAFETY_BITS = {
    SafetyMode.NORMAL: (1 << 0),
    SafetyMode.REDUCED: (1 << 1),
    SafetyMode.PROTECTIVE_STOP: (1 << 2) | (1 << 10),
    SafetyMode.RECOVERY: (1 << 3),
    SafetyMode.SAFEGUARD_STOP: (1 << 4) | (1 << 10),
    SafetyMode.SYSTEM_EMERGENCY_STOP: (1 << 5) | (1 << 7) | (1 << 10),
    SafetyMode.ROBOT_EMERGENCY_STOP: (1 << 6) | (1 << 7) | (1 << 10),
    SafetyMode.VIOLATION: (1 << 8) | (1 << 10),
    SafetyMode.FAULT: (1 << 9) | (1 << 10),
}

# commands of the rtde_control script (ur_rtde RTDE::RobotCommand::Type)
CMD_NO = 0
CMD_MOVEJ = 1
CMD_SERVOJ = 11
CMD_SERVO_STOP = 16
CMD_PROTECTIVE_STOP = 31
CMD_STOPL = 33
CMD_STOPJ = 34
CMD_SET_WATCHDOG = 35
CMD_MOVE_PATH = 45
CMD_IS_STEADY = 47
CMD_WATCHDOG = 99
CMD_STOP_SCRIPT = 255
_REALTIME = {24, 11, 9, 10, 6, 25, 26, 27, 38, 58}
"""Commands the script processes without the done/clear handshake (its main loop's list)."""

_MOVEJ_LINE = re.compile(
    r"movej\(\[([^\]]*)\]\s*,\s*a\s*=\s*([-+0-9.eE]+)\s*,\s*v\s*=\s*([-+0-9.eE]+)\s*(?:,\s*r\s*=\s*([-+0-9.eE]+))?\s*\)"
)
_INT_OFFSET = re.compile(r"global\s+reg_offset_int\s*=\s*(\d+)")


@dataclass(frozen=True)
class UrIdentity:
    """What the controller says it is (dashboard and RTDE version)."""

    model: str = "UR10"
    serial: str = "20235500001"
    polyscope: str = "5.11.1.108318"

    @property
    def version(self) -> tuple[int, int, int, int]:
        parts = [int(p) for p in self.polyscope.split(".")]
        return (parts + [0, 0, 0, 0])[:4]  # type: ignore[return-value]


class _Stop:
    """Decelerate every joint proportionally at ``decel`` (rad/s², leading axis) to rest."""

    def __init__(self, q: NDArray[np.float64], qd: NDArray[np.float64], decel: float) -> None:
        self.q0, self.qd0 = q.copy(), qd.copy()
        vmax = float(np.abs(qd).max())
        self.duration = vmax / decel if vmax > 0 else 0.0

    def at(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        if t >= self.duration or self.duration == 0:
            T = self.duration
            return self.q0 + self.qd0 * T / 2, np.zeros(6)
        k = 1.0 - t / self.duration
        return self.q0 + self.qd0 * (t - t * t / (2 * self.duration)), self.qd0 * k


class UrController:
    """State and behaviour of the emulated controller (thread-safe; all under one lock).

    Args:
        q0: initial joints (rad).
        identity: model, serial and PolyScope version.
        robot_mode: initial robot mode (``RUNNING``: powered, brakes released).
        remote_control: whether the pendant is in remote control mode.
        joint_limits: (6, 2) position limits its safety system enforces (rad).
        unlock_delay_s: the wait after a protective stop before the dashboard may unlock it
            (a real controller: 5 s).
        stop_decel: deceleration of protective/emergency stops (rad/s², leading axis).
        tcp_error_m: an offset added to the reported TCP pose (emulates a wrong robot model).
    """

    def __init__(
        self,
        q0: NDArray[np.float64],
        identity: UrIdentity | None = None,
        robot_mode: RobotMode = RobotMode.RUNNING,
        remote_control: bool = True,
        joint_limits: NDArray[np.float64] | None = None,
        unlock_delay_s: float = 5.0,
        stop_decel: float = 10.0,
        tcp_error_m: float = 0.0,
    ) -> None:
        self.lock = threading.RLock()
        self.identity = identity or UrIdentity()
        self.q = np.asarray(q0, dtype=np.float64).copy()
        self.qd = np.zeros(6)
        self.robot_mode = robot_mode
        self.safety_mode = SafetyMode.NORMAL
        self.runtime_state = RuntimeState.STOPPED
        self.remote_control = remote_control
        self.joint_limits = rm.JOINT_LIMITS.copy() if joint_limits is None else np.asarray(joint_limits, dtype=float)
        self.unlock_delay_s = unlock_delay_s
        self.stop_decel = stop_decel
        self.tcp_error_m = tcp_error_m
        self.speed_slider = 1.0
        self.in_int = [0] * 48
        self.in_double = [0.0] * 48
        self.out_int = [0] * 48
        self.out_double = [0.0] * 48
        self.t_start = time.monotonic()
        self._protective_since = 0.0
        self._estop_pressed = False
        self._motion: Trajectory | _Stop | None = None
        self._motion_t = 0.0
        self._path: list[Trajectory] = []
        self._path_i = 0
        self._async = False
        self._sync_pending = False
        self._async_wr = 0
        self._async_op = 0
        self._script_running = False
        self._executing = False
        self._stale_cmd: int | None = None
        """The command code in the register when the program started (from the program before)."""
        self._off = 0
        self._path_script: list[tuple[NDArray[np.float64], float, float]] = []
        self._watchdog_period = 0.0
        self._last_input = time.monotonic()
        self.messages: list[str] = []
        """Controller log (the pendant's log tab): faults, script events."""

    # --- state as RTDE publishes it ----------------------------------------------------------

    def safety_status_bits(self) -> int:
        return _SAFETY_BITS.get(self.safety_mode, 0)

    def robot_status_bits(self) -> int:
        powered = self.robot_mode in (RobotMode.POWER_ON, RobotMode.IDLE, RobotMode.RUNNING)
        return (1 if powered else 0) | (2 if self.runtime_state == RuntimeState.PLAYING else 0)

    def tcp_pose(self) -> list[float]:
        T = rm.fk(self.q)
        p = T[:3, 3] + np.array([self.tcp_error_m, 0.0, 0.0])
        return [*p.tolist(), *Rotation.from_matrix(T[:3, :3]).as_rotvec().tolist()]

    def snapshot(self) -> dict[str, object]:
        """The output variables' values now, registers aside (see :meth:`register`)."""
        now = time.monotonic()
        q, qd = self.q.tolist(), self.qd.tolist()
        tcp = self.tcp_pose()
        st: dict[str, object] = {
            "timestamp": now - self.t_start,
            "target_q": q,
            "actual_q": q,
            "target_qd": qd,
            "actual_qd": qd,
            "target_qdd": [0.0] * 6,
            "actual_TCP_pose": tcp,
            "target_TCP_pose": tcp,
            "robot_mode": int(self.robot_mode),
            "safety_mode": int(self.safety_mode),
            "safety_status_bits": self.safety_status_bits(),
            "robot_status_bits": self.robot_status_bits(),
            "runtime_state": int(self.runtime_state),
            "speed_scaling": self.speed_slider if self.safety_mode == SafetyMode.NORMAL else 0.0,
            "target_speed_fraction": self.speed_slider,
            "joint_mode": [253 if self.robot_mode == RobotMode.RUNNING else 236] * 6,
            "actual_execution_time": 0.1,
            "actual_main_voltage": 48.0,
            "actual_robot_voltage": 48.0 if self.robot_mode >= RobotMode.POWER_ON else 0.0,
            "joint_temperatures": [30.0] * 6,
        }
        return st

    def register(self, name: str) -> int | float | bool:
        """A register's value by its RTDE name (``output_int_register_3``, …)."""
        kind, _, idx = name.rpartition("_")
        i = int(idx)
        table = {
            "output_int_register": self.out_int,
            "output_double_register": self.out_double,
            "input_int_register": self.in_int,
            "input_double_register": self.in_double,
        }.get(kind)
        return table[i] if table is not None and i < 48 else False

    # --- inputs -----------------------------------------------------------------------------

    def set_input(self, name: str, value: object) -> None:
        """An input variable arrived in a data package (caller holds the lock)."""
        self._last_input = time.monotonic()
        kind, _, idx = name.rpartition("_")
        if kind == "input_int_register":
            self.in_int[int(idx)] = int(value)  # type: ignore[call-overload]
        elif kind == "input_double_register":
            self.in_double[int(idx)] = float(value)  # type: ignore[arg-type]

    # --- the script -------------------------------------------------------------------------

    def upload_script(self, text: str) -> None:
        """A program arrived on the script port: start it if the robot can run programs."""
        with self.lock:
            if "def rtde_control" not in text:
                self.messages.append("script ignored: only ur_rtde's rtde_control program is emulated")
                return
            if not self.remote_control:
                self.messages.append("script refused: the robot is in local control mode")
                log.warning("script refused: the robot is in local control mode")
                return
            if self.robot_mode != RobotMode.RUNNING or self.safety_mode not in (SafetyMode.NORMAL, SafetyMode.REDUCED):
                why = f"program not started: robot mode {self.robot_mode.name}, safety mode {self.safety_mode.name}"
                self.messages.append(why)
                log.warning(why)
                return
            m = _INT_OFFSET.search(text)
            self._off = int(m.group(1)) if m else 0
            body = text.split("def exec_move_path():", 1)
            path: list[tuple[NDArray[np.float64], float, float]] = []
            if len(body) == 2:
                block = body[1].split("\n    end", 1)[0]
                for mm in _MOVEJ_LINE.finditer(block):
                    q = np.array([float(x) for x in mm.group(1).split(",")])
                    path.append((q, float(mm.group(3)), float(mm.group(2))))
            self._path_script = path
            self._halt(self.stop_decel)  # a new program replaces a running one
            self._script_running = True
            self._watchdog_period = 0.0  # a program sets its own watchdog (rtde_set_watchdog)
            # A real controller needs ≥ 50 ms to start a program, so the command register holds the
            # client's clear (0) by then; this one starts at once, so the code still left from before
            # (the stop-script that preceded the upload) is stale: not run while the register holds it.
            # Any other value is the new program's own: the clear and the next command can land between
            # two ticks (RTDE reader thread delayed under load), so waiting for a 0 would miss the
            # command and leave ur-rtde waiting for "done" forever (the demo's hung moveJ(path)).
            self._executing = False
            self._stale_cmd = self.in_int[self._off] if self.in_int[self._off] != CMD_NO else None
            self.runtime_state = RuntimeState.PLAYING
            self._signal_async_finished()  # reset_async_progress
            self.out_int[self._off + 0] = 1  # signal_ready
            self.messages.append("RTDE Control Script Loaded")
            log.info("program started (%d path entries)", len(path))

    def _write_async(self, value: int) -> None:
        """The script's async status register: op id (bits 24–30), write count (16–23), running
        (bit 15) and progress (0–14); ``value`` < 0 means finished."""
        self._async_wr = 0 if self._async_wr >= 127 else self._async_wr + 1
        if value == 0:
            self._async_op = 0 if self._async_op >= 127 else self._async_op + 1
        reg = self._async_wr * 65536 + self._async_op * 16777216
        if value >= 0:
            reg += min(value, 32767) + 32768
        self.out_int[self._off + 2] = reg

    def _signal_async_finished(self) -> None:
        self._write_async(-1)

    def _end_script(self, why: str) -> None:
        if self._script_running:
            self.messages.append(f"program stopped: {why}")
            log.warning("program stopped: %s", why)
        self._script_running = False
        self._sync_pending = False
        self.runtime_state = RuntimeState.STOPPED

    def _check_target(self, q: NDArray[np.float64]) -> bool:
        lo, hi = self.joint_limits[:, 0], self.joint_limits[:, 1]
        if np.any(q < lo) or np.any(q > hi) or q.shape != (6,) or not np.isfinite(q).all():
            self.protective_stop(f"joint position limit violation: target {np.round(q, 4).tolist()}")
            return False
        return True

    def _movej(self, targets: list[tuple[NDArray[np.float64], float, float]]) -> bool:
        segs: list[Trajectory] = []
        q = self.q.copy()
        for target, v, a in targets:
            if not self._check_target(target):
                return False
            # movej: v and a are the leading axis's; no joint beyond the UR10e's own limits
            lim = JointLimits(np.minimum(np.full(6, v), UR10E.velocity), np.full(6, min(a, UR10E_JOINT_ACCEL_CEILING)))
            segs.append(time_parametrize([q, target], lim, 1.0))
            q = target
        self._path, self._path_i = segs, 0
        self._motion, self._motion_t = (segs[0] if segs else None), 0.0
        return True

    def _halt(self, decel: float) -> None:
        """Kill the motion; decelerate from where the arm is."""
        self._path, self._path_i = [], 0
        if self._motion is not None or np.abs(self.qd).max() > 0:
            self._motion, self._motion_t = _Stop(self.q, self.qd, max(decel, 1e-3)), 0.0
        if self._async:
            self._async = False
            self._signal_async_finished()

    def _process(self, cmd: int) -> None:
        o = self._off
        if cmd != CMD_WATCHDOG and log.isEnabledFor(logging.DEBUG):
            log.debug("command %d (async %d, arg %.3g)", cmd, self.in_int[o + 1], self.in_double[o])
        if cmd == CMD_MOVEJ or cmd == CMD_MOVE_PATH:
            asynchronous = self.in_int[o + 1] == 1
            if cmd == CMD_MOVEJ:
                q = np.array(self.in_double[o : o + 6])
                targets = [(q, self.in_double[o + 6], self.in_double[o + 7])]
            else:
                targets = list(self._path_script)
            self._halt(self.stop_decel)
            if not self._movej(targets):
                return
            if asynchronous:
                self._async = True
                self._write_async(0)
            else:
                self._sync_pending = True
                return  # done is signalled when the motion ends (process_cmd blocks in URScript)
        elif cmd in (CMD_STOPJ, CMD_STOPL, CMD_SERVO_STOP):
            self._halt(max(self.in_double[o], 1e-3))
            if cmd != CMD_SERVO_STOP and self.in_int[o + 1] != 1 and self._motion is not None:
                self._sync_pending = True  # a synchronous stopj returns when the arm is at rest
                return
        elif cmd == CMD_SERVOJ:
            q = np.array(self.in_double[o : o + 6])
            if self._check_target(q):
                dt = max(self.in_double[o + 8], 0.002)
                # follow the set point in ``t`` s, no joint beyond its speed limit
                step = np.clip((q - self.q) / dt, -UR10E.velocity, UR10E.velocity)
                self._motion, self._path = None, []
                self.qd = step
            return
        elif cmd == CMD_PROTECTIVE_STOP:
            self.protective_stop("triggered by the program (protective_stop())")
            return
        elif cmd == CMD_SET_WATCHDOG:
            f = self.in_double[o]
            self._watchdog_period = 1.0 / f if f > 0 else 0.0
        elif cmd == CMD_IS_STEADY:
            self.out_int[o + 1] = 1 if self._motion is None and np.abs(self.qd).max() == 0 else 0
        elif cmd == CMD_STOP_SCRIPT:
            self._halt(self.stop_decel)
            self._end_script("stop script received")
            return
        elif cmd in _REALTIME or cmd == CMD_WATCHDOG:
            return
        else:
            self._halt(self.stop_decel)
            self._end_script(f"command {cmd} is not emulated (script runtime error)")
            return
        self.out_int[o + 0] = 2  # signal_done_with_cmd

    def _script_step(self) -> None:
        if not self._script_running or self._sync_pending:
            return
        o = self._off
        cmd = self.in_int[o]
        if self._stale_cmd is not None:
            if cmd == self._stale_cmd:
                return
            self._stale_cmd = None
        if cmd in _REALTIME:
            self._process(cmd)
            if self._script_running:
                self.out_int[o] = 1
        elif cmd == CMD_NO:
            self._executing = False
            self.out_int[o] = 1
        elif not self._executing:
            self._executing = True
            self._process(cmd)

    # --- time -------------------------------------------------------------------------------

    def tick(self, dt: float) -> None:
        """Advance ``dt`` seconds of controller time (caller: the 500 Hz loop)."""
        with self.lock:
            if self._watchdog_period and self._script_running:
                gap = time.monotonic() - self._last_input
                if gap > self._watchdog_period:
                    self._halt(self.stop_decel)
                    self._end_script(f"RTDE input watchdog expired (no input for {1e3 * gap:.0f} ms)")
            self._advance(dt)
            self._script_step()

    def _advance(self, dt: float) -> None:
        if self._motion is None:
            if np.abs(self.qd).max() > 0:  # servoj: integrate the set-point velocity for one step
                self.q = self.q + self.qd * dt
                self.qd = np.zeros(6)
            return
        scale = self.speed_slider if isinstance(self._motion, Trajectory) else 1.0
        if self.safety_mode == SafetyMode.REDUCED and isinstance(self._motion, Trajectory):
            scale *= 0.3  # reduced mode: the safety system scales speed down
        self._motion_t += dt * scale
        q, qd = self._motion.at(self._motion_t)
        self.q, self.qd = q, qd * scale
        if self._motion_t < self._motion.duration:
            return
        self.qd = np.zeros(6)
        if isinstance(self._motion, Trajectory) and self._path_i + 1 < len(self._path):
            self._path_i += 1
            self._motion, self._motion_t = self._path[self._path_i], 0.0
            if self._async:
                self._write_async(self._path_i)
            return
        was_stop = isinstance(self._motion, _Stop)
        self._motion, self._path = None, []
        if self._async and not was_stop:
            self._async = False
            self._signal_async_finished()
        if self._sync_pending:
            self._sync_pending = False
            self.out_int[self._off] = 2

    @property
    def moving(self) -> bool:
        with self.lock:
            return self._motion is not None or bool(np.abs(self.qd).max() > 0)

    # --- safety and the dashboard's commands ---------------------------------------------------

    def protective_stop(self, why: str) -> None:
        with self.lock:
            self._halt(self.stop_decel)
            self.safety_mode = SafetyMode.PROTECTIVE_STOP
            self._protective_since = time.monotonic()
            self._end_script(f"protective stop: {why}")
            self.messages.append(f"PROTECTIVE STOP: {why}")

    def emergency_stop(self, pressed: bool = True) -> None:
        """Press (or release) the emergency stop button."""
        with self.lock:
            if pressed:
                self._halt(self.stop_decel)
                self._estop_pressed = True
                self.safety_mode = SafetyMode.ROBOT_EMERGENCY_STOP
                self._end_script("emergency stop")
                self.messages.append("EMERGENCY STOP")
            elif self._estop_pressed:
                self._estop_pressed = False
                self.safety_mode = SafetyMode.NORMAL
                self.robot_mode = RobotMode.POWER_OFF  # category 1: the arm was powered down

    def safeguard_stop(self, active: bool = True) -> None:
        with self.lock:
            if active:
                self._halt(self.stop_decel)
                self.safety_mode = SafetyMode.SAFEGUARD_STOP
                self._end_script("safeguard stop")
            elif self.safety_mode == SafetyMode.SAFEGUARD_STOP:
                self.safety_mode = SafetyMode.NORMAL

    def reduced_mode(self, active: bool = True) -> None:
        with self.lock:
            if active and self.safety_mode == SafetyMode.NORMAL:
                self.safety_mode = SafetyMode.REDUCED
            elif not active and self.safety_mode == SafetyMode.REDUCED:
                self.safety_mode = SafetyMode.NORMAL

    def power(self, on: bool) -> str:
        with self.lock:
            if not on:
                self._halt(self.stop_decel)
                self._end_script("power off")
                self.robot_mode = RobotMode.POWER_OFF
                return "Powering off"
            if self._estop_pressed:
                return "Cannot power on: emergency stop is active"
            if self.robot_mode == RobotMode.POWER_OFF:
                self.robot_mode = RobotMode.IDLE
            return "Powering on"

    def brake_release(self) -> str:
        with self.lock:
            if self.robot_mode == RobotMode.IDLE:
                self.robot_mode = RobotMode.RUNNING
            return "Brake releasing"

    def unlock_protective_stop(self) -> str:
        with self.lock:
            if self.safety_mode != SafetyMode.PROTECTIVE_STOP:
                return "Cannot unlock protective stop: the robot is not protective stopped"
            if time.monotonic() - self._protective_since < self.unlock_delay_s:
                return (
                    f"Cannot unlock protective stop until {self.unlock_delay_s:g}s after occurrence. "
                    "Always inspect cause of protective stop before unlocking"
                )
            self.safety_mode = SafetyMode.NORMAL
            return "Protective stop releasing"

    def stop_program(self) -> str:
        with self.lock:
            if not self._script_running:
                return "Stopped"  # nothing to stop (ur-rtde's reuploadScript stops the script first, then this)
            self._halt(self.stop_decel)
            self._end_script("stopped from the dashboard")
            return "Stopped"
