"""approaching: park the base beside the bin and bring the camera to an observation pose."""

from __future__ import annotations

from cellctl.messages import ApproachReply, ApproachRequest
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import Step


class Approaching(Step):
    NAME = "approaching"
    OUTCOMES = ("succeeded", "failed")
    DESCRIPTION = "park beside the bin (first attempt) and move to observation pose k"
    READS = ("observation_index",)
    WRITES = ("approach",)

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        first = ctx.approach is None
        req = ApproachRequest(observation_index=ctx.observation_index, park=first)
        reply, _ = run.call("robot", "approach", req, ApproachReply)
        ctx.approach = reply
        return "succeeded"
