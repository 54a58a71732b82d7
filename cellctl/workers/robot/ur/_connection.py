"""The UR backend's link to the controller: connect (checked: model, serial, remote control, mode,
safety) with back-off, bounded sending calls, (re)start of the control program, ``stopJ``, and
the RTDE state reads every other part works from.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from cellctl.config import UrConfig
from cellctl.errors import RobotError
from cellctl.geometry import robot_model as rm
from cellctl.workers.robot._planned import PlannedRobot, TwinBaseReport
from cellctl.workers.robot.ur._calls import T_CMD, T_PATH, CallThread, Refused, Wedged, dispose
from cellctl.workers.robot.ur._rtde import RTDE_VARIABLES

__all__ = ["UrConnection"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


class UrConnection(TwinBaseReport, PlannedRobot):
    """The connection layer of :class:`~cellctl.workers.robot.ur.UrRobot` (its state is set in ``UrRobot.__init__``)."""

    io: threading.Lock
    ur: UrConfig
    _c: Any
    _r: Any
    _d: Any
    _calls: CallThread
    _last_state: dict[str, Any] | None
    _motion_seq: int
    _q_meas: NDArray[np.float64] | None
    _tcp: NDArray[np.float64] | None
    _ts: float
    _data_t: float
    _runtime: int
    speed_slider: float | None

    def _connect(self) -> None:
        """Connect with doubling back-off; refusals that retrying cannot fix raise at once."""
        delay = 0.25
        last: Exception | None = None
        for attempt in range(self.ur.connect_attempts):
            try:
                self._connect_once()
                return
            except Refused as err:
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
                raise Refused(
                    f"wrong robot model: the dashboard reports {model!r} (PolyScope {version}, i.e. {name}); "
                    f"robot.ur.expected_model is {self.ur.expected_model!r}"
                )
            if self.ur.expected_serial is not None:
                serial = d.getSerialNumber().strip()
                if serial != self.ur.expected_serial:
                    raise Refused(
                        f"wrong robot: serial number {serial!r}, "
                        f"robot.ur.expected_serial is {self.ur.expected_serial!r}"
                    )
            if not d.isInRemoteControl():
                raise Refused("the robot is in local control mode: switch the pendant to remote control")
            mode = d.robotmode().split(":")[-1].strip()
            if mode != "RUNNING":
                raise Refused(
                    f"the robot is not in RUNNING mode (robot mode {mode}); power it on and release the brakes "
                    "(maintenance actions power_on, brake_release)"
                )
            safety = d.safetystatus().split(":")[-1].strip()
            if safety not in ("NORMAL", "REDUCED"):
                raise Refused(f"the robot's safety status is {safety}; clear it on the pendant or by maintenance")
            try:
                self._r = rtde_receive.RTDEReceiveInterface(host, 125.0, RTDE_VARIABLES)
                self._c = rtde_control.RTDEControlInterface(host)
                self._calls.close()
                self._calls = CallThread("ur-control-calls")
                self._send(T_CMD, self._c.setWatchdog, self.ur.faults.watchdog_hz)
            except RuntimeError as err:
                if "already in use" in str(err) or "not found" in str(err).lower():
                    raise Refused(f"the controller refused ur-rtde's RTDE recipe: {err}") from None
                raise
            self._read_state()
        log.info("connected to %s at %s (PolyScope %s)", name, host, version)
        self._check_tcp()

    def _send(self, timeout_s: float, fn: Callable[..., Any], *args: Any, fatal: bool = True) -> Any:
        """A sending control call, bounded (caller holds :attr:`io`); an overrun gives the interface up
        (unless not ``fatal``: then :class:`Late`).

        Raises:
            RuntimeError: ur-rtde's error, :class:`Wedged` (overrun, or given up before) or :class:`Late`.
        """
        t0 = time.monotonic()
        try:
            return self._calls.call(timeout_s, fn, *args, fatal=fatal)
        except Wedged:
            c, self._c = self._c, None
            if c is not None:
                log.error("UR control interface given up: %s", self._calls.wedged)
                threading.Thread(target=dispose, args=(c,), name="ur-dispose", daemon=True).start()
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
        dispose(*handles)

    def _reupload(self) -> None:
        """Send the control program again and wait until it runs (caller holds :attr:`io`).

        ur-rtde's ``reuploadScript`` returns once the script is sent, before the program starts.
        """
        if not self._send(T_PATH, self._c.reuploadScript):
            raise RobotError(f"could not send the control program to {self.ur.host}")
        deadline = time.monotonic() + 10.0  # a real controller: ≈ 0.1 s; a loaded shared machine: seconds
        while not self._c.isProgramRunning():
            if time.monotonic() > deadline:
                raise RobotError("the control program did not start within 10 s (robot mode, safety or local control?)")
            time.sleep(0.005)
        self._send(T_CMD, self._c.setWatchdog, self.ur.faults.watchdog_hz)

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
                    self._send(T_CMD, self._c.stopJ, self.ur.stop_decel, False)
                except RuntimeError as err:
                    log.warning("stopJ failed: %s", err)

    # --- state ------------------------------------------------------------------------------

    def _read_state(self, r: Any = None) -> dict[str, Any]:
        """One poll of the RTDE state of ``r`` (default: the current receive interface).

        The receive interface's getters are cache reads under its own mutex: the monitor polls
        without :attr:`io`, so a control call that blocks (a stalled controller holds ``moveJ``)
        cannot hide the stall from it.
        """
        r = self._r if r is None else r
        st: dict[str, Any] = {
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
