"""checking_cache: ask the planner for a cached plan of this bin type within pose tolerance."""

from __future__ import annotations

from cellctl.errors import PlanCacheError
from cellctl.messages import PlanLookupReply, PlanLookupRequest, PoseMsg
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import Step


class CheckingCache(Step):
    NAME = "checking_cache"
    OUTCOMES = ("hit", "miss", "failed")
    DESCRIPTION = "plan-cache lookup + tolerance check + viewpoint adjustment (in the planner worker)"
    READS = ("bin_type", "T_base_bin", "params", "mode")
    WRITES = ("plan",)

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        req = PlanLookupRequest(
            bin_type=ctx.bin_type or "",
            bin_pose=PoseMsg.from_matrix(ctx.T_base_bin),
            surface=ctx.surface,
            # data collection visits every reachable viewpoint, not only the tour
            all_reachable=ctx.mode == "collect",
        )
        reply, _ = run.call("planner", "lookup", req, PlanLookupReply, timeout=ctx.cfg.supervisor.timeouts.default)
        if not reply.hit:
            run.event("info", f"no usable plan: {reply.reason}")
            return "miss"
        if not reply.viewpoints:
            raise PlanCacheError(f"planner answered lookup with a hit on plan {reply.plan_id!r} but no viewpoints")
        ctx.plan = reply
        note = " (viewpoints adjusted to the measured pose)" if reply.adjusted else ""
        run.event("info", f"plan {reply.plan_id} with {len(reply.viewpoints)} viewpoints{note}")
        return "hit"
