"""The UR backend's maintenance: an operator's explicit commands (dashboard actions, ``clear_fault``)."""

from __future__ import annotations

import logging
import time

from cellctl.errors import RobotError
from cellctl.messages import RobotMaintenanceReply, RobotMaintenanceRequest
from cellctl.workers.robot.ur._calls import T_CMD, T_PATH
from cellctl.workers.robot.ur._rtde import classify_fault
from cellctl.workers.robot.ur._safety import UrSafety

__all__ = ["UrMaintenance"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


class UrMaintenance(UrSafety):
    """The maintenance layer of :class:`~cellctl.workers.robot.ur.UrRobot`: never automatic."""

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
        if not self._busy.acquire(timeout=T_CMD + T_PATH):
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
                    self._send(T_CMD, self._c.setWatchdog, self.ur.faults.watchdog_hz)
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
