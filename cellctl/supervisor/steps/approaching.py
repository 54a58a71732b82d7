"""approaching: park the base beside the bin and bring the camera to an observation pose.

In a whole-bin cycle the base parks at the current station's planned pose (bin frame) once the
stations are known (the first park, before the bin is identified, is the nominal one); at a
station that cannot see the board the arm stays tucked (identifying carries the pose over).
Each park keeps the pose the base reports for it (``T_map_base``: the twin's in the approach
reply, else the Base driver's localisation) for that carrying over.

The base parks through the Base interface (``base.backend``) first: ``manual`` waits here for
the operator's/PLC's ``base_parked`` command (timeout ``base.confirm_timeout_s``), ``sim``
leaves the drive to the twin. Then the robot worker is told the base is parked (``park``).
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

import numpy as np

from cellctl.messages import ApproachReply, ApproachRequest
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import AT_STATION, Step

if TYPE_CHECKING:
    from cellctl.workers.base import Base


def approach_request(run: StepRun, observation_index: int, park: bool) -> ApproachRequest:
    """The ApproachRequest for the station the cycle is at (the nominal park when there is none)."""
    st = run.ctx.stations.current_station()
    if st is None:
        return ApproachRequest(observation_index=observation_index, park=park)
    return ApproachRequest(
        observation_index=observation_index,
        park=park,
        base_pose=st.base_pose,
        observe=st.observation_index is not None,
    )


def reported_base_pose(reply: ApproachReply, base: Base | None) -> np.ndarray | None:
    """``T_map_base`` the base reports for this park: the twin's, in the approach reply, else the Base
    driver's localisation; None when neither reports one."""
    if reply.base_pose is not None and reply.base_pose.frame_id == "map":
        return reply.base_pose.matrix()
    T = base.pose() if base is not None else None
    return None if T is None else np.asarray(T, dtype=np.float64)


class Approaching(Step):
    NAME = "approaching"
    OUTCOMES = ("succeeded", "failed")
    DESCRIPTION = "park beside the bin (at the station, first attempt) and move to observation pose k"
    READS = ("identity.observation_index",)
    CONSULTS = (*AT_STATION, "identity.approach")
    WRITES = ("identity.approach", "stations.T_map_base")

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        first = ctx.identity.approach is None
        st = ctx.stations.current_station()
        if first and st is not None:
            run.event(
                "info",
                f"station {ctx.stations.station_index + 1}/{len(ctx.stations.station_order)} "
                f"(plan station {st.station}): parking",
            )
        if first and ctx.base is not None:
            self._park_base(run, st.station if st is not None else 0)
        req = approach_request(run, ctx.identity.observation_index, first)
        reply, _ = run.call("robot", "approach", req, ApproachReply)
        ctx.identity.approach = reply
        if first:  # a new park: only this park's report may carry a pose to it
            ctx.stations.T_map_base = reported_base_pose(reply, ctx.base)
        return "succeeded"

    @staticmethod
    def _park_base(run: StepRun, station: int) -> None:
        """Park the base at ``station`` (blocking); a cancelled step stops the base. Raises RobotError."""
        base = run.ctx.base
        assert base is not None
        if base.NEEDS_CONFIRMATION:
            run.event(
                "info",
                f"waiting for the base to be parked at station {station}: confirm with a Command "
                f'{{"base_parked": {station}}} (cellctl cmd --base-parked {station})',
            )
        done = threading.Event()

        def watch() -> None:  # a Hold/Stop/Abort cancels the step: the base must not go on driving
            while not done.wait(0.05):
                if run.cancelled.is_set():
                    base.stop(f"{run.name} cancelled")
                    return

        threading.Thread(target=watch, name="base-watch", daemon=True).start()
        try:
            base.park(station)
        finally:
            done.set()
        run.checkpoint()
