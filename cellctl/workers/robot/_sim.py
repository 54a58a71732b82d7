"""The simulated robot: UR10e on a mobile base in the twin's cell.

Motions follow the :mod:`cellctl.motion` trajectory of the planned path (the same one the UR
backend sends to the controller) in simulated time × ``robot.speed_scale``; joints are updated
along the way (published by the worker), and :meth:`SimRobot.stop` interrupts a motion where
it is.

The twin's mobile base reports where it parked (:class:`TwinBaseReport`): the true park plus
its localisation error (``base.localisation_error_m``/``_deg``), on every approach reply.
"""

from __future__ import annotations

import logging
import time

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import RobotError
from cellctl.workers.robot._planned import DRIVE_S, FROZEN_GAP_S, PlannedRobot, TwinBaseReport

__all__ = ["DRIVE_S", "FROZEN_GAP_S", "SimRobot"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


class SimRobot(TwinBaseReport, PlannedRobot):
    """The sim backend of the robot role (see :class:`PlannedRobot` for the arguments)."""

    publishes_twin = True

    def _execute(self, path: NDArray[np.float64]) -> float:
        traj = self.trajectory(path)
        scale = self.cfg.robot.speed_scale
        total = traj.duration / scale
        dt = 1.0 / self.cfg.robot.joint_state_hz
        t0 = time.monotonic()
        last = t0
        self._moving = True
        try:
            while True:
                now = time.monotonic()
                self._check_not_frozen(max(now - last, now - self._tick), "motion")
                if self._stop.is_set():  # before moving: a stop that came during planning holds
                    raise RobotError(
                        f"motion stopped ({self._stop_reason or 'stop requested'}) at joints "
                        f"{np.round(self.joints, 4).tolist()}"
                    )
                last = now
                t = now - t0
                q = path[-1].copy() if t >= total else traj.at(t * scale)[0]
                with self._lock:
                    self._q = q
                self._changed()
                if t >= total:
                    return total
                time.sleep(min(dt, total - t))
        finally:
            self._moving = False
