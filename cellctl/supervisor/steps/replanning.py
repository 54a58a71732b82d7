"""replanning: abort-to-offline — submit a planning job; the next cycle finds the plan.

A whole-bin cycle without a whole-bin plan submits a whole-bin job (stations, both surfaces);
a miss at a known station (the base parked beyond tolerance there) replans that station's
surface at the measured pose, an ordinary plan the next lookup at that station finds.
"""

from __future__ import annotations

import time

from cellctl.bus import keys
from cellctl.errors import PlanningError
from cellctl.messages import CycleOutcome, PlanJobQuery, PlanJobReply, PlanJobRequest, PoseMsg
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import AT_STATION, Step


class Replanning(Step):
    NAME = "replanning"
    OUTCOMES = ("submitted", "plan_ready", "failed")
    DESCRIPTION = "submit an offline planning job; end with replan_required (or wait, by config)"
    READS = ("identity.bin_type", "identity.T_base_bin")
    CONSULTS = (*AT_STATION, "identity.approach")
    WRITES = ("scan.planner_job_id", "result.outcome", "result.reason", "stations.planned")

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        pc = ctx.cfg.planner
        req = PlanJobRequest(
            bin_type=ctx.identity.bin_type or "",
            bin_pose=PoseMsg.from_matrix(ctx.identity.T_base_bin),
            surface=ctx.surface,
            seed_pct=pc.seed_pct,
            mode=pc.mode,
            seed=pc.seed,
            # the tour starts where the arm is now: at the observation pose it identified from
            q_start=list(ctx.identity.approach.joints) if ctx.identity.approach is not None else None,
            whole=ctx.whole and ctx.stations.planned is None,
        )
        st = ctx.stations.current_station()
        key = keys.planner_jobs(ctx.cfg.cell_id)
        reply, _ = run.call(
            "planner", "jobs", req, PlanJobReply, key=key, timeout=ctx.cfg.supervisor.timeouts.plan_submit
        )
        ctx.scan.planner_job_id = reply.job_id
        what = "whole-bin " if req.whole else f"station {st.station} {ctx.surface} " if st is not None else ""
        run.event("info", f"{what}planning job {reply.job_id} submitted for bin {ctx.identity.bin_type!r}")
        if not ctx.cfg.supervisor.wait_for_plan:
            ctx.result.outcome = CycleOutcome.replan_required
            where = f" at station {st.station} ({ctx.surface})" if st is not None else ""
            ctx.result.reason = (
                f"no {'whole-bin plan' if req.whole else 'plan within tolerance'} "
                f"for bin {ctx.identity.bin_type!r}{where}; "
                f"{what}planning job {reply.job_id} submitted"
            )
            return "submitted"
        deadline = time.monotonic() + ctx.cfg.supervisor.timeouts.plan_wait
        while time.monotonic() < deadline:
            run.checkpoint()
            status, _ = run.call("planner", "jobs", PlanJobQuery(job_id=reply.job_id), PlanJobReply, key=key)
            if status.state == "done":
                if status.reason:  # e.g. no plan sees enough of this bin for a clean verdict (cellctl.seen)
                    run.event("warning", f"planning job {reply.job_id}: {status.reason}")
                if req.whole:
                    ctx.stations.planned = None  # the next lookup reads the new plan's stations
                return "plan_ready"
            if status.state == "failed":
                raise PlanningError(f"planning job {reply.job_id} failed: {status.reason}")
            run.cancelled.wait(1.0)
        raise PlanningError(f"planning job {reply.job_id} not done within {ctx.cfg.supervisor.timeouts.plan_wait:g} s")
