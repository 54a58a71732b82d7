"""The UR backend's safety monitor, watchdog kicks and fault latch.

A monitor thread polls the RTDE state at ``robot.ur.faults.monitor_hz`` (100 Hz: ≤ 10 ms plus the
8 ms RTDE period to notice) and latches a **fault** on protective stop, emergency stop, safeguard
stop, reduced mode, a robot mode other than RUNNING, a lost or stale RTDE connection, or the
control program stopping during a motion. A fault stops the motion (``stopJ``), refuses further
motions and is only cleared by an explicit maintenance command. The controller's RTDE watchdog
(``setWatchdog``) stops the program if this worker stops kicking it (a frozen worker, a dropped
link), so a motion never outlives its worker.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from cellctl.messages import FaultCondition, FaultReport
from cellctl.workers.robot.ur._calls import T_KICK, Late
from cellctl.workers.robot.ur._connection import UrConnection
from cellctl.workers.robot.ur._rtde import (
    PLAYING,
    ROBOT_MODES,
    SAFETY_FLAGS,
    SAFETY_MODES,
    classify_fault,
    condition_of,
)

__all__ = ["UrSafety"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


class UrSafety(UrConnection):
    """The safety layer of :class:`~cellctl.workers.robot.ur.UrRobot` (its threads start in ``UrRobot.__init__``)."""

    on_fault: Callable[[FaultReport], None] | None
    _fault: str | None
    fault_report: FaultReport | None
    _fault_motion: int
    fault_log: list[tuple[float, str]]
    _monitor_stop: threading.Event

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
                        found = (condition_of(name), name)
                    # this connection's samples may still show the program restart moveJ(path) does:
                    # only a stop that lasts beyond a few RTDE periods is one
                    if not (self._moving and st["runtime"] != PLAYING):
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
            if self._runtime != PLAYING or not self.io.acquire(timeout=period):
                continue
            try:
                if self._linked() and not self._calls.busy:
                    self._send(T_KICK, self._c.kickWatchdog, fatal=False)
            except Late as err:
                log.warning("UR watchdog kick late: %s", err)
            except RuntimeError as err:  # Wedged: the monitor names it (the interface is given up)
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
            robot_mode=ROBOT_MODES.get(int(st["mode"]), str(st["mode"])),
            safety_mode=SAFETY_MODES.get(int(st["safety_mode"]), str(st["safety_mode"])),
            safety_status_bits=bits,
            safety_flags=[name for bit, name in SAFETY_FLAGS if bits & (1 << bit)],
        )
