"""The UR backend's motions: a planned path as one asynchronous ``moveJ(path)``, watched to its end.

The planned path, timed by :mod:`cellctl.motion`, goes to the controller as **one asynchronous**
``moveJ(path)`` with blend radius 0, not as ``servoJ`` streaming. Why: the controller then runs the
trajectory in its own 500 Hz loop — a Python worker on a loaded machine cannot hold a 2–8 ms servo
deadline, and a missed deadline is a jerk or a protective stop on a real arm; blend 0 keeps the
arm on the collision-checked straight segments (the motion module's profile per segment is the
controller's ``movej`` profile: same leading-axis speed and acceleration), and the asynchronous
call leaves the worker free to watch safety, the supervisor's token and its own stalls while the
arm moves, and to ``stopJ`` at any moment.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import RobotError
from cellctl.messages import ApproachReply, ApproachRequest, MoveReply, MoveRequest, WashReply, WashRequest
from cellctl.workers.robot.ur._calls import T_CMD, T_PATH, Wedged
from cellctl.workers.robot.ur._safety import UrSafety

__all__ = ["UrMotion", "path_deviation"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


def path_deviation(path: NDArray[np.float64], q: NDArray[np.float64]) -> float:
    """Largest joint deviation (rad) of ``q`` from the nearest point of the piecewise-linear ``path``."""
    best = float(np.abs(q - path[0]).max())
    for a, b in zip(path[:-1], path[1:], strict=True):
        d = b - a
        den = float(d @ d)
        s = 0.0 if den == 0 else float(np.clip((q - a) @ d / den, 0.0, 1.0))
        best = min(best, float(np.abs(q - (a + s * d)).max()))
    return best


class UrMotion(UrSafety):
    """The motion layer of :class:`~cellctl.workers.robot.ur.UrRobot`."""

    tracking: deque[float]

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
                ok = self._send(T_PATH, self._c.moveJ, entries, True)
                if ok:  # moveJ(path) restarted the program: its watchdog with it
                    self._send(T_CMD, self._c.setWatchdog, self.ur.faults.watchdog_hz)
                log.debug("motion %d sent (%d entries, %.2f s): %s", motion, len(entries), traj.duration, ok)
        except Wedged as err:
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
                    off = float(np.abs(q - path[-1]).max())
                    if off <= self.ur.joint_tolerance_rad:
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
                                    motion, 1e3 * (time.monotonic() - now), off,
                                )  # fmt: skip
                                self._check_tcp()
                                return now - t0
                            off = float(np.abs(q - path[-1]).max())
                        if self._fault is not None:
                            raise RobotError(f"motion aborted: UR fault ({self._fault}) at {np.round(q, 4).tolist()}")
                        raise RobotError(f"the motion ended {off:.4f} rad short of its goal (stopped)")
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
