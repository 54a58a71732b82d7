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
from cellctl.messages import ApproachReply, ApproachRequest, PoseMsg
from cellctl.sim import scene
from cellctl.workers.robot._planned import DRIVE_S, FROZEN_GAP_S, PlannedRobot

__all__ = ["DRIVE_S", "FROZEN_GAP_S", "SimRobot", "TwinBaseReport"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


class TwinBaseReport:
    """For a twin-backed :class:`PlannedRobot` (put it first in the bases): the twin parks the base,
    so the twin's base reports its pose, ``ApproachReply.base_pose`` (frame ``map``, the twin's world).

    A station whose board is not visible then gets the bin pose measured at an earlier station
    carried through the base's reported motion, so only the localisation error is left
    unmeasured there, not the parking error. Only the ``sim`` base reports: a ``manual`` one is
    parked by a person, with no localisation to report; a worker without the twin (a real
    controller) knows nothing of the base (a vendor base reports through :meth:`Base.pose`).
    """

    def approach(self, req: ApproachRequest) -> ApproachReply:
        reply = super().approach(req)  # type: ignore[misc]
        twin = getattr(self, "publishes_twin", False)  # a real controller's worker knows nothing of the base
        if not twin or self.cfg.base.backend != "sim" or not self._parked:  # type: ignore[attr-defined]
            return reply
        b = self.cfg.base  # type: ignore[attr-defined]
        T = scene.localised(self._scenario, b.localisation_error_m, b.localisation_error_deg, self._park_attempt)  # type: ignore[attr-defined]
        return reply.model_copy(update={"base_pose": PoseMsg.from_matrix(T, "map")})


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
