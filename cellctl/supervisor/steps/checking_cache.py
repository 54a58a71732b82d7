"""checking_cache: ask the planner for a cached plan of this bin type within pose tolerance.

In a whole-bin cycle the lookup also answers the newest whole-bin plan's stations. The first
lookup of a cycle fixes the station loop: it starts at the station the first park matched
(its plan within tolerance) and goes round the plan's order; a first park that matches none
(or the whole plan's first station lies elsewhere) drives to the plan's first station
(outcome ``move``). A miss at a known station replans that station (replanning).
"""

from __future__ import annotations

from cellctl.errors import PlanCacheError, PlanningError
from cellctl.messages import PlanLookupReply, PlanLookupRequest, PoseMsg
from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import AT_STATION, Step


class CheckingCache(Step):
    NAME = "checking_cache"
    OUTCOMES = ("hit", "miss", "move", "failed")
    DESCRIPTION = "plan-cache lookup + tolerance check + viewpoint adjustment (in the planner worker)"
    READS = ("identity.bin_type", "identity.T_base_bin", "stations.bin_poses", "stations.pose_source", "stations.plans")
    CONSULTS = AT_STATION
    WRITES = (
        "scan.plan",
        "stations.plans",
        "stations.planned",
        "stations.whole_plan_id",
        "stations.modelled_cycle_s",
        "stations.station_order",
        "stations.station_index",
        "stations.surface_index",
        "stations.bin_poses",
        "stations.pose_source",
        "identity.approach",
        "identity.observation_index",
        "identity.identify_attempts",
    )

    def _lookup(self, run: StepRun) -> PlanLookupReply:
        ctx = run.ctx
        req = PlanLookupRequest(
            bin_type=ctx.identity.bin_type or "",
            bin_pose=PoseMsg.from_matrix(ctx.identity.T_base_bin),
            surface=ctx.surface,
            # data collection visits every reachable viewpoint, not only the tour
            all_reachable=ctx.mode == "collect",
            whole=ctx.whole,
        )
        reply, _ = run.call("planner", "lookup", req, PlanLookupReply, timeout=ctx.cfg.supervisor.timeouts.default)
        return reply

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        asked = ctx.surface
        reply = self._lookup(run)
        if ctx.whole and reply.whole_plan_id is not None and not reply.stations:
            # the whole-bin planner found no station for this bin: replanning would find none again
            raise PlanningError(reply.reason or f"whole-bin plan {reply.whole_plan_id} has no station")
        if ctx.whole and ctx.stations.planned is None and reply.stations:
            ranks = [s.station for s in reply.stations]
            ctx.stations.planned = reply.stations
            ctx.stations.whole_plan_id = reply.whole_plan_id
            ctx.stations.modelled_cycle_s = reply.cycle_time_s
            if not reply.hit or reply.station is None:
                ctx.stations.station_order, ctx.stations.station_index, ctx.stations.surface_index = ranks, 0, 0
                st = ctx.stations.current_station()
                assert st is not None
                ctx.identity.approach = None  # park again, at the station
                ctx.identity.observation_index = st.observation_index or 0
                ctx.identity.identify_attempts = 0
                run.event(
                    "info",
                    f"parked at no station of whole-bin plan {reply.whole_plan_id} ({reply.reason}); "
                    f"driving to its station {st.station}",
                )
                return "move"
            k = ranks.index(reply.station)
            ctx.stations.station_order, ctx.stations.station_index, ctx.stations.surface_index = (
                ranks[k:] + ranks[:k],
                0,
                0,
            )
            assert ctx.identity.T_base_bin is not None  # the lookup above sent it
            ctx.stations.bin_poses[reply.station] = ctx.identity.T_base_bin
            ctx.stations.pose_source[reply.station] = "measured"
            run.event(
                "info",
                f"whole-bin plan {reply.whole_plan_id}: {len(ranks)} stations, starting at station {reply.station}",
            )
            if ctx.surface != asked:  # this station's first surface is not the one the first lookup asked for
                reply = self._lookup(run)
        if not reply.hit:
            here = ctx.stations.current_station()
            where = f" at station {here.station} ({ctx.surface})" if here is not None else ""
            run.event("info", f"no usable plan{where}: {reply.reason}")
            return "miss"
        if not reply.viewpoints:
            raise PlanCacheError(f"planner answered lookup with a hit on plan {reply.plan_id!r} but no viewpoints")
        ctx.scan.plan = reply
        st = ctx.stations.current_station()
        ctx.stations.plans[(st.station if st is not None else None, ctx.surface if st is not None else None)] = reply
        note = " (viewpoints adjusted to the measured pose)" if reply.adjusted else ""
        where = f"station {st.station}, {ctx.surface}: " if st is not None else ""
        run.event("info", f"{where}plan {reply.plan_id} with {len(reply.viewpoints)} viewpoints{note}")
        return "hit"
