"""wash_check and washing: Start mode ``wash_and_verify`` (issue 17).

After reporting, ``wash_check`` reads the cycle's dirt map: no dirty face → the bin is
``clean``; dirt left after ``wash.max_rounds`` rounds, or dirt no nozzle pose reaches from
where the base is parked → ``dirty`` with the reason and the remaining faces; else it plans the
round's wash (the planner worker's ``wash_plan`` op, :func:`cellctl.washing.plan.plan_wash` at
the measured bin pose from the arm's joints now: the supervisor never imports the planning
stack) and ``washing`` runs it: one robot ``wash`` request per sweep, so a Hold resumes at
the next sweep and a sweep the robot refuses costs only its faces. ``verifying``
(:mod:`cellctl.supervisor.steps.verifying`) re-inspects what was washed and loops back here.

Every other mode passes ``wash_check`` straight through (outcome ``done``). Per round the plan
goes to the cycle log (:data:`~cellctl.bus.topics.WASH_PLAN`) and the pictures (dirt map
before, wash path on the mesh, dirt map after) beside the cycle's MCAP, in ``<cycle_id>.wash/``.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from cellctl.bus import topics
from cellctl.errors import PlanningError, WorkerFailed
from cellctl.messages import (
    PoseMsg,
    RobotState,
    RobotStateRequest,
    WashPlanReply,
    WashPlanRequest,
    WashReply,
    WashRequest,
    WashResult,
    WashSweep,
)
from cellctl.supervisor.context import CycleContext, StepRun
from cellctl.supervisor.steps._base import Step

__all__ = ["WashCheck", "Washing", "face_mask", "picture_dir"]


def picture_dir(ctx: CycleContext) -> Path | None:
    """Where the cycle's wash pictures go: ``<cycle_id>.wash/`` beside its MCAP (None: no log on disk)."""
    path = getattr(ctx.log, "path", None)
    return Path(path).parent / f"{ctx.cycle_id}.wash" if path is not None else None


def face_mask(ids: list[int], n_faces: int) -> np.ndarray:
    """(F,) bool of a face id list (a WashPlanReply's ``dirty``, ``targets``, ...)."""
    out = np.zeros(n_faces, bool)
    out[np.asarray(ids, np.int64)] = True
    return out


def _plan_view(plan: WashPlanReply, n_faces: int, T_bin_base: np.ndarray) -> Any:  # noqa: ANN401
    """What :func:`cellctl.washing.pictures.draw_wash_path` reads of a plan, from the planner's reply."""
    return SimpleNamespace(
        dirty=face_mask(plan.dirty, n_faces),
        targets=face_mask(plan.targets, n_faces),
        washed=face_mask(plan.washed, n_faces),
        unwashable=[SimpleNamespace(faces=np.asarray(u.faces, np.int64), area_m2=u.area_m2) for u in plan.unwashable],
        sweeps=plan.sweeps,
        stations=[T_bin_base],
    )


def _spot_passes(plan: WashPlanReply) -> list[Any]:
    """Each sweep's spot path once per pass, back and forth (as the twin runs them)."""
    out = []
    for sw in plan.sweeps:
        fwd = SimpleNamespace(spots=np.asarray(sw.spots).reshape(-1, 3), axes=np.asarray(sw.axes).reshape(-1, 3))
        back = SimpleNamespace(spots=fwd.spots[::-1], axes=fwd.axes[::-1])
        out += [fwd if k % 2 == 0 else back for k in range(sw.passes)]
    return out


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
        if ctx.whole:
            # the rounds wash and re-inspect from one park; a whole-bin cycle ends at its last station
            why = "not washed: wash_and_verify runs in single-station cycles (planner.whole.enabled is true)"
            return self._end(run, None, why)
        mesh = wash_mesh(ctx)
        dirty = _dirty_faces(ctx, mesh)
        if not dirty.any():
            return self._end(run, "clean", None, dirty, mesh)
        area = float(mesh.areas[dirty].sum())
        if done >= wc.max_rounds:
            why = f"dirt left after {done} wash round(s) (wash.max_rounds): {int(dirty.sum())} faces"
            why += f", {area * 1e4:.0f} cm²"
            return self._end(run, "dirty", why, dirty, mesh)
        plan = self._plan(run, done + 1)
        ctx.log.write_json(topics.WASH_PLAN, "cellctl.WashPlan", {"round": done + 1, **plan.summary})
        if not plan.sweeps:
            why = f"unwashable: {plan.reason}"
            return self._end(run, "dirty", why, dirty, mesh, plan.summary.get("unwashable", []))
        ctx.wash_plan = plan
        ctx.wash_next_sweep = 0
        ctx.wash_next_view = 0
        ctx.wash_run = {"sweeps_run": 0, "passes_run": 0, "refused": [], "pictures": []}
        n_unw = len(plan.unwashable)
        run.event(
            "info",
            f"wash round {done + 1}: {int(dirty.sum())} dirty faces ({area * 1e4:.0f} cm²) → {len(plan.sweeps)} "
            f"sweeps planned in {plan.plan_s:.1f} s" + (f"; {n_unw} piece(s) unwashable from here" if n_unw else ""),
        )
        self._pictures(ctx, mesh, plan, done + 1)
        return "wash"

    @staticmethod
    def _plan(run: StepRun, r: int) -> WashPlanReply:
        from cellctl.geometry.transforms import invert

        ctx = run.ctx
        wc = ctx.cfg.wash
        state, _ = run.call("robot", "state", RobotStateRequest(), RobotState)
        assert ctx.T_base_bin is not None and ctx.bin_type is not None  # wash_mesh checked them
        req = WashPlanRequest(
            bin_type=ctx.bin_type,
            # the base stays where the cycle parked it: the one station is the measured pose
            stations=[PoseMsg.from_matrix(invert(ctx.T_base_bin), "bin")],
            q_start=state.joints,
            dirt_map=ctx.dirt_map,
            threshold=wc.threshold,
            margin_m=wc.margin_m,
            seed=ctx.params.seed,
            round=r,
        )
        reply, _ = run.call("planner", "wash_plan", req, WashPlanReply)
        return reply

    @staticmethod
    def _pictures(ctx: CycleContext, mesh: Any, plan: WashPlanReply, r: int) -> None:  # noqa: ANN401
        folder = picture_dir(ctx)
        if folder is None:
            return
        from cellctl.geometry.transforms import invert
        from cellctl.recording.dirt_map import draw_dirt_map
        from cellctl.washing.pictures import draw_wash_path

        assert ctx.T_base_bin is not None
        name = ctx.bin_type or "bin"
        view = _plan_view(plan, mesh.n_faces, invert(ctx.T_base_bin))
        before = draw_dirt_map(mesh, ctx.dirt_map or {}, folder / f"r{r}_before.png", f"{name} round {r}: before")
        path = draw_wash_path(mesh, view, _spot_passes(plan), folder / f"r{r}_path.png", f"{name} round {r}:")
        ctx.wash_run["pictures"] = [before.name, path.name]  # in <cycle_id>.wash/: a replay's names match

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
                sweeps=[WashSweep(joints=sw.joints, passes=sw.passes, region=sw.region)],
                round=r,
            )
            try:
                try:
                    reply, _ = run.call("robot", "wash", req, WashReply)
                except WorkerFailed as err:
                    run.checkpoint()
                    if "no collision-free path" not in str(err) or len(sw.joints) < 2:
                        raise
                    # the transit to one end found no path in the robot's time: the other end may be easier
                    back = WashSweep(joints=sw.joints[::-1], passes=sw.passes, region=sw.region)
                    reply, _ = run.call("robot", "wash", WashRequest(sweeps=[back], round=r), WashReply)
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
