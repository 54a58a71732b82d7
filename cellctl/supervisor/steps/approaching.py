"""approaching: park the base beside the bin and bring the camera to an observation pose.

In a whole-bin cycle the base parks at the current station's planned pose (bin frame) once the
stations are known (the first park, before the bin is identified, is the nominal one); at a
station that cannot see the board the arm stays tucked (identifying carries the pose over).
"""

from __future__ import annotations

from cellctl.messages import ApproachReply, ApproachRequest
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import Step


def approach_request(run: StepRun, observation_index: int, park: bool) -> ApproachRequest:
    """The ApproachRequest for the station the cycle is at (the nominal park when there is none)."""
    st = run.ctx.current_station()
    if st is None:
        return ApproachRequest(observation_index=observation_index, park=park)
    return ApproachRequest(
        observation_index=observation_index,
        park=park,
        base_pose=st.base_pose,
        observe=st.observation_index is not None,
    )


class Approaching(Step):
    NAME = "approaching"
    OUTCOMES = ("succeeded", "failed")
    DESCRIPTION = "park beside the bin (at the station, first attempt) and move to observation pose k"
    READS = ("observation_index",)
    WRITES = ("approach",)

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        first = ctx.approach is None
        st = ctx.current_station()
        if first and st is not None:
            run.event(
                "info",
                f"station {ctx.station_index + 1}/{len(ctx.station_order)} (plan station {st.station}): parking",
            )
        req = approach_request(run, ctx.observation_index, first)
        reply, _ = run.call("robot", "approach", req, ApproachReply)
        ctx.approach = reply
        return "succeeded"
