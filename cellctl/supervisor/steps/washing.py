"""wash_check and washing: Start mode ``wash_and_verify`` (issue 17).

After reporting, ``wash_check`` reads the cycle's dirt map: no dirty face → the bin is
``clean``; dirt left after ``wash.max_rounds`` rounds, or dirt no nozzle pose reaches from
where the base is parked → ``dirty`` with the reason and the remaining faces; else it plans the
round's wash (:func:`cellctl.washing.plan.plan_wash` at the measured bin pose, from the arm's
joints now) and ``washing`` runs it: one robot ``wash`` request per sweep, so a Hold resumes at
the next sweep and a sweep the robot refuses costs only its faces. ``verifying``
(:mod:`cellctl.supervisor.steps.verifying`) re-inspects what was washed and loops back here.

Every other mode passes ``wash_check`` straight through (outcome ``done``). Per round the plan
goes to the cycle log (:data:`~cellctl.bus.topics.WASH_PLAN`) and the pictures (dirt map
before, wash path on the mesh, dirt map after) beside the cycle's MCAP, in ``<cycle_id>.wash/``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cellctl.bus import topics
from cellctl.errors import PlanningError, WorkerFailed
from cellctl.messages import RobotState, RobotStateRequest, WashReply, WashRequest, WashResult, WashSweep
from cellctl.supervisor.context import CycleContext, StepRun
from cellctl.supervisor.steps._base import Step

__all__ = ["WashCheck", "Washing", "picture_dir", "unwashable_summary"]


def picture_dir(ctx: CycleContext) -> Path | None:
    """Where the cycle's wash pictures go: ``<cycle_id>.wash/`` beside its MCAP (None: no log on disk)."""
    path = getattr(ctx.log, "path", None)
    return Path(path).parent / f"{ctx.cycle_id}.wash" if path is not None else None


def unwashable_summary(plan: Any, mesh: Any) -> list[dict[str, Any]]:  # noqa: ANN401 - WashPlan, BinMesh
    return plan.summary(mesh)["unwashable"]


def wash_mesh(ctx: CycleContext) -> Any:  # noqa: ANN401 - BinMesh
    if ctx.catalog is None or ctx.bin_type is None or ctx.T_base_bin is None:
        raise PlanningError("a wash needs the identified bin (type, mesh and pose); the cycle has none")
    return ctx.catalog.load_mesh(ctx.bin_type)


def _dirty_faces(ctx: CycleContext, mesh: Any) -> np.ndarray:  # noqa: ANN401
    from cellctl.washing.targets import dirty_from_map

    dirty, _ = dirty_from_map(ctx.dirt_map or {}, mesh.n_faces, ctx.cfg.wash.threshold)
    return dirty


class WashCheck(Step):
    NAME = "wash_check"
    OUTCOMES = ("done", "wash", "failed")
    DESCRIPTION = "wash_and_verify: clean, dirty (rounds spent / unwashable), or plan the next round's wash"
    READS = ("mode", "dirt_map")
    WRITES = ("wash_plan", "wash", "verdict")

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        if ctx.mode != "wash_and_verify":
            return "done"
        wc = ctx.cfg.wash
        done = len(ctx.wash_rounds)
        if ctx.dirt_map is None:
            return self._end(run, None, "no dirt map: the wash needs the cycle's dirt map (nothing was inspected)")
        mesh = wash_mesh(ctx)
        dirty = _dirty_faces(ctx, mesh)
        if not dirty.any():
            return self._end(run, "clean", None, dirty, mesh)
        area = float(mesh.areas[dirty].sum())
        if done >= wc.max_rounds:
            why = f"dirt left after {done} wash round(s) (wash.max_rounds): {int(dirty.sum())} faces"
            why += f", {area * 1e4:.0f} cm²"
            return self._end(run, "dirty", why, dirty, mesh)
        plan = self._plan(run, mesh)
        ctx.log.write_json(topics.WASH_PLAN, "cellctl.WashPlan", {"round": done + 1, **plan.summary(mesh)})
        if not plan.moves:
            why = f"unwashable: {plan.reason}"
            return self._end(run, "dirty", why, dirty, mesh, unwashable_summary(plan, mesh))
        ctx.wash_plan = plan
        ctx.wash_next_sweep = 0
        ctx.wash_next_view = 0
        ctx.wash_run = {"sweeps_run": 0, "passes_run": 0, "refused": [], "pictures": []}
        n_unw = len(plan.unwashable)
        run.event(
            "info",
            f"wash round {done + 1}: {int(dirty.sum())} dirty faces ({area * 1e4:.0f} cm²) → {len(plan.sweeps)} "
            f"sweeps planned in {plan.times_s.get('total', 0.0):.1f} s"
            + (f"; {n_unw} piece(s) unwashable from here" if n_unw else ""),
        )
        self._pictures(ctx, mesh, plan, done + 1)
        return "wash"

    @staticmethod
    def _plan(run: StepRun, mesh: Any) -> Any:  # noqa: ANN401 - BinMesh → WashPlan
        from cellctl.geometry.transforms import invert
        from cellctl.planning.robot import default_robot_model
        from cellctl.washing.nozzle import NozzleModel
        from cellctl.washing.plan import WashParams, plan_wash

        ctx = run.ctx
        wc = ctx.cfg.wash
        state, _ = run.call("robot", "state", RobotStateRequest(), RobotState)
        params = WashParams(
            threshold=wc.threshold, margin_m=wc.margin_m, seed=ctx.params.seed, q_start=tuple(state.joints)
        )
        assert ctx.T_base_bin is not None  # wash_mesh checked it
        # the base stays where the cycle parked it: the one station is the measured pose
        return plan_wash(
            mesh,
            ctx.dirt_map,
            [invert(ctx.T_base_bin)],
            NozzleModel.from_config(ctx.cfg.nozzle),
            default_robot_model(),
            params,
        )

    @staticmethod
    def _pictures(ctx: CycleContext, mesh: Any, plan: Any, r: int) -> None:  # noqa: ANN401
        folder = picture_dir(ctx)
        if folder is None:
            return
        from cellctl.recording.dirt_map import draw_dirt_map
        from cellctl.washing.nozzle import NozzleModel
        from cellctl.washing.pictures import draw_wash_path
        from cellctl.washing.spots import plan_spots

        name = ctx.bin_type or "bin"
        spots = plan_spots(plan, mesh, NozzleModel.from_config(ctx.cfg.nozzle))
        before = draw_dirt_map(mesh, ctx.dirt_map or {}, folder / f"r{r}_before.png", f"{name} round {r}: before")
        path = draw_wash_path(mesh, plan, spots, folder / f"r{r}_path.png", f"{name} round {r}:")
        ctx.wash_run["pictures"] = [f"{folder.name}/{p.name}" for p in (before, path)]

    @staticmethod
    def _end(
        run: StepRun,
        verdict: str | None,
        reason: str | None,
        dirty: np.ndarray | None = None,
        mesh: Any = None,  # noqa: ANN401
        unwashable: list[dict[str, Any]] | None = None,
    ) -> str:
        ctx = run.ctx
        remaining = np.flatnonzero(dirty).tolist() if dirty is not None else []
        area = float(mesh.areas[dirty].sum()) if dirty is not None and mesh is not None else 0.0
        ctx.wash = WashResult(
            verdict=verdict,  # type: ignore[arg-type]
            reason=reason,
            rounds=list(ctx.wash_rounds),
            remaining_faces=remaining,
            remaining_m2=round(area, 6),
            unwashable=unwashable or [],
        )
        ctx.wash_plan = None
        if verdict is not None:
            ctx.verdict = verdict  # type: ignore[assignment]
        n = len(ctx.wash_rounds)
        run.event(
            "info" if verdict == "clean" else "warning",
            f"wash and verify: {verdict or 'no verdict'} after {n} round(s)" + (f" ({reason})" if reason else ""),
        )
        return "done"


class Washing(Step):
    NAME = "washing"
    OUTCOMES = ("succeeded", "failed")
    DESCRIPTION = "run the round's wash sweeps on the robot, one request per sweep (a Hold resumes at the next)"
    READS = ("wash_plan",)
    WRITES = ("wash_next_sweep", "wash_run")

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        plan = ctx.wash_plan
        assert plan is not None  # READS wash_plan
        r = len(ctx.wash_rounds) + 1
        stats = ctx.wash_run
        for i in range(ctx.wash_next_sweep, len(plan.sweeps)):
            sw = plan.sweeps[i]
            req = WashRequest(
                sweeps=[WashSweep(joints=sw.q.tolist(), passes=sw.passes, region=sw.region)],
                round=r,
            )
            try:
                reply, _ = run.call("robot", "wash", req, WashReply)
            except WorkerFailed as err:
                run.checkpoint()  # a Hold/Stop interrupts the sweep: not a refusal, resume it
                # one refused sweep (newly in collision at the measured pose) costs its faces, not the round
                stats["refused"].append({"sweep": i, "reason": str(err)[:300]})
                ctx.wash_next_sweep = i + 1
                continue
            stats["sweeps_run"] += reply.sweeps_run
            stats["passes_run"] += reply.passes_run
            ctx.wash_next_sweep = i + 1
        if stats["sweeps_run"] == 0:
            first = stats["refused"][0]["reason"] if stats["refused"] else "none planned"
            raise WorkerFailed(f"robot ran none of the {len(plan.sweeps)} wash sweeps (first: {first})", role="robot")
        run.event(
            "info",
            f"wash round {r}: {stats['sweeps_run']}/{len(plan.sweeps)} sweeps, {stats['passes_run']} passes run"
            + (f", {len(stats['refused'])} refused" if stats["refused"] else ""),
        )
        return "succeeded"
