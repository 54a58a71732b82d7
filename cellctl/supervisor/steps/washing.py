"""wash_check and washing: Start mode ``wash_and_verify`` (issue 17).

After reporting, ``wash_check`` reads the cycle's dirt map: no dirty face → the bin is
``clean`` when the scan and re-inspections saw enough of it (``wash.min_seen_fraction`` of its area and
``classifier.verdict.min_seen_fraction`` of each surface), else ``incomplete``; dirt left after
``wash.max_rounds`` rounds, or dirt no nozzle pose reaches from where the base is parked → ``dirty``
with the reason and the remaining faces; else it plans the round's wash (the planner worker's
``wash_plan`` op, :func:`cellctl.washing.plan.plan_wash` at the measured bin pose from the arm's
joints now: the supervisor never imports the planning stack) and ``washing`` runs it: one robot
``wash`` request per sweep, so a Hold resumes at the next sweep and a sweep the robot refuses
costs only its faces. ``verifying``
(:mod:`cellctl.supervisor.steps.verifying`) re-inspects what was washed and loops back here.

**Whole-bin cycles** (``planner.whole.enabled``): the round's plan is asked for every station the
scan used, each with the bin pose its plans were adjusted to, and each sweep belongs to one of
them. ``wash_station`` then walks the stations the round needs — the one the base stands at first,
then the others — parking at each (``wash_approaching`` → ``wash_identifying``: the station's bin
pose measured again, or carried over as the scan did), and ``washing`` runs that station's sweeps
(replanned for its share of the faces at the pose measured now when the base parked again). The
re-inspection goes the same way, station by station, with each station's own plans' viewpoints.
The place in the walk (``wash_queue``, ``verify_queue``, ``wash_next_sweep``, ``wash_next_view``)
is on the blackboard, so a Hold resumes at the station and sweep or view where it stopped.

Every other mode passes ``wash_check`` straight through (outcome ``done``). Per round the plan
goes to the cycle log (:data:`~cellctl.bus.topics.WASH_PLAN`) and the pictures (dirt map
before, wash path on the mesh, dirt map after) beside the cycle's MCAP, in ``<cycle_id>.wash/``.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast

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
from cellctl.seen import gate_verdict
from cellctl.supervisor.context import CycleContext, StepRun
from cellctl.supervisor.steps._base import AT_STATION, Step
from cellctl.supervisor.steps.reporting import surface_fractions
from cellctl.surface import Surface

__all__ = [
    "WashCheck",
    "WashStation",
    "Washing",
    "face_mask",
    "face_state",
    "picture_dir",
    "round_poses",
    "seen_fraction",
    "verify_stations",
    "views_at",
]


def picture_dir(ctx: CycleContext) -> Path | None:
    """Where the cycle's wash pictures go: ``<cycle_id>.wash/`` beside its MCAP (None: no log on disk)."""
    path = getattr(ctx.log, "path", None)
    return Path(path).parent / f"{ctx.cycle_id}.wash" if path is not None else None


def face_mask(ids: list[int], n_faces: int) -> np.ndarray:
    """(F,) bool of a face id list (a WashPlanReply's ``dirty``, ``targets``, ...)."""
    out = np.zeros(n_faces, bool)
    out[np.asarray(ids, np.int64)] = True
    return out


def _plan_view(plan: WashPlanReply, n_faces: int, T_bin_base: list[np.ndarray]) -> Any:
    """What :func:`cellctl.washing.pictures.draw_wash_path` reads of a plan, from the planner's reply."""
    return SimpleNamespace(
        dirty=face_mask(plan.dirty, n_faces),
        targets=face_mask(plan.targets, n_faces),
        washed=face_mask(plan.washed, n_faces),
        unwashable=[SimpleNamespace(faces=np.asarray(u.faces, np.int64), area_m2=u.area_m2) for u in plan.unwashable],
        sweeps=plan.sweeps,
        stations=T_bin_base,
    )


def _spot_passes(plan: WashPlanReply) -> list[Any]:
    """Each sweep's spot path once per pass, back and forth (as the twin runs them)."""
    out = []
    for sw in plan.sweeps:
        fwd = SimpleNamespace(spots=np.asarray(sw.spots).reshape(-1, 3), axes=np.asarray(sw.axes).reshape(-1, 3))
        back = SimpleNamespace(spots=fwd.spots[::-1], axes=fwd.axes[::-1])
        out += [fwd if k % 2 == 0 else back for k in range(sw.passes)]
    return out


def wash_mesh(ctx: CycleContext) -> Any:  # BinMesh
    if ctx.catalog is None or ctx.identity.bin_type is None or ctx.identity.T_base_bin is None:
        raise PlanningError("a wash needs the identified bin (type, mesh and pose); the cycle has none")
    return ctx.catalog.load_mesh(ctx.identity.bin_type)


def wash_ranks(ctx: CycleContext) -> list[int | None]:
    """The stations a round may wash from, in the order it walks them: the one the base stands at,
    then the others back along the scan's visiting order (a single-station cycle: ``[None]``)."""
    if not ctx.whole or not ctx.wash.scan_poses:
        return [None]
    here = ctx.wash.parked
    rest: list[int | None] = [r for r in reversed(ctx.stations.station_order) if r in ctx.wash.scan_poses and r != here]
    return ([here] if here in ctx.wash.scan_poses else []) + rest


def park_at(run: StepRun, rank: int | None, why: str) -> bool:
    """Make the base stand at station ``rank`` for washing/re-inspection: True when it already
    does; else sets the station loop's place there for ``wash_approaching`` → ``wash_identifying``
    (the new park's bin pose is measured again, or carried over) and returns False."""
    ctx = run.ctx
    if rank is None or rank == ctx.wash.parked:
        return True
    ctx.stations.station_index = ctx.stations.station_order.index(rank)
    ctx.stations.surface_index = 0
    st = ctx.stations.current_station()
    assert st is not None
    ctx.identity.approach = None  # the base drives: park at the station
    ctx.identity.observation_index = st.observation_index or 0
    ctx.identity.identify_attempts = 0
    ctx.wash.parked = rank
    # sweeps planned at the scan's park of this station would miss by the new park's error
    ctx.wash.station_sweeps.pop(rank, None)
    run.event("info", f"wash round {len(ctx.wash.rounds) + 1}: parking at station {rank} to {why}")
    return False


def washed_faces(ctx: CycleContext, n: int) -> np.ndarray:
    """(F,) faces the round's sweeps that ran sprayed to their passes (every station's)."""
    return face_mask(list(ctx.wash.run.get("washed", [])), n)


def look_faces(ctx: CycleContext, mesh: Any) -> np.ndarray:
    """(F,) what the round re-inspects: its targets and every face its jet sprayed, dilated by the splash."""
    from cellctl.washing.targets import dilate

    wplan = ctx.wash.plan
    assert wplan is not None
    n = mesh.n_faces
    sprayed = face_mask(wplan.targets, n) | face_mask(wplan.washed, n) | washed_faces(ctx, n)
    return dilate(mesh, sprayed, ctx.cfg.wash.splash_m)


def views_at(ctx: CycleContext, mesh: Any, rank: int | None) -> list[tuple[Surface, Any]]:
    """(surface, PlannedViewpoint) of station ``rank``'s plans that see a face to look at, in plan order."""
    look = look_faces(ctx, mesh)
    n = mesh.n_faces
    if rank is None:
        assert ctx.scan.plan is not None
        pairs = [(ctx.surface, vp) for vp in ctx.scan.plan.viewpoints]
    else:  # a whole-bin cycle's plans are keyed by their surface
        pairs = [
            (cast(Surface, surf), vp)
            for (st, surf), p in ctx.stations.plans.items()
            if st == rank
            for vp in p.viewpoints
        ]
    return [(s, vp) for s, vp in pairs if any(0 <= f < n and look[f] for f in vp.faces)]


def round_poses(ctx: CycleContext) -> list[np.ndarray]:
    """T_base_bin of each station a round plans for, in :func:`wash_ranks` order.

    Single-station: the measured pose (the base stays where the cycle parked it). Whole-bin: the
    pose each station's plans were adjusted to in the scan, except the station the base stands at
    now, which is at the pose measured at *this* park. A later round starts where the last
    re-inspection parked the base, a park again since the scan (2-3 cm, 1° off it); planned at the
    scan's pose its sweeps were off by that error and nothing replanned them (no re-park follows):
    on the twin 2 of 4 such round-2 sweeps were refused in collision, all 4 ran when planned here.
    The other stations are replanned at the pose measured when the base parks there
    (``Washing._replan``)."""
    if not ctx.whole:
        assert ctx.identity.T_base_bin is not None
        return [ctx.identity.T_base_bin]
    here = ctx.wash.parked
    return [
        ctx.stations.bin_poses[r] if r == here and r in ctx.stations.bin_poses else ctx.wash.scan_poses[r]
        for r in cast(list[int], wash_ranks(ctx))  # whole-bin: every rank is a station
    ]


def verify_stations(ctx: CycleContext) -> list[int | None]:
    """The stations the round re-inspects from, in the order walked (the base's station first)."""
    mesh = wash_mesh(ctx)
    return [r for r in wash_ranks(ctx) if views_at(ctx, mesh, r)]


def face_state(dirt_map: dict[str, Any], n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(p, seen, dirty) per face of a dirt map, the coarse kind (face id lists) as p = 1 dirty / 0 clean."""
    from cellctl.classify.heatmap import face_probabilities

    dirty = np.zeros(n, bool)
    dirty[np.asarray(dirt_map.get("seen_dirty", []), np.int64)] = True
    p = face_probabilities(dirt_map, n)
    if p is not None:
        seen = ~np.isnan(p)
        return np.nan_to_num(p, nan=0.0), seen, dirty
    seen = dirty.copy()
    seen[np.asarray(dirt_map.get("seen_clean", []), np.int64)] = True
    return dirty.astype(float), seen, dirty


def seen_fraction(ctx: CycleContext, mesh: Any) -> float:
    """Share of the bin's area (both surfaces) the cycle's dirt map has seen: the scan's views and every
    round's re-inspection merged (faces with a probability, or in a coarse map's seen lists).

    A clean verdict is a statement about these faces only: powder where no view looks is not seen,
    and not washed (docs/washing/README.md, the seed-20 twin run)."""
    _, seen, _ = face_state(ctx.result.dirt_map or {}, mesh.n_faces)
    total = float(mesh.areas.sum())
    return float(mesh.areas[seen].sum()) / total if total > 0 else 0.0


def _dirty_faces(ctx: CycleContext, mesh: Any) -> np.ndarray:
    from cellctl.washing.targets import dirty_from_map

    dirty, _ = dirty_from_map(ctx.result.dirt_map or {}, mesh.n_faces, ctx.cfg.wash.threshold)
    return dirty


class WashCheck(Step):
    NAME = "wash_check"
    OUTCOMES = ("done", "wash", "failed")
    DESCRIPTION = "wash_and_verify: clean, dirty (rounds spent / unwashable), or plan the next round's wash"
    READS = (
        "result.dirt_map",
        "wash.rounds",
        "wash.scan_poses",
        "stations.bin_poses",
        "stations.station_order",
        "identity.bin_type",
        "identity.T_base_bin",
    )
    CONSULTS = ("wash.parked",)
    WRITES = (
        "wash.plan",
        "wash.result",
        "wash.next_sweep",
        "wash.next_view",
        "wash.run",
        "wash.queue",
        "wash.verify_queue",
        "wash.phase",
        "wash.scan_poses",
        "wash.parked",
        "wash.station_sweeps",
        "result.verdict",
        "result.reason",
        "result.coverage_by_surface",
    )

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        if ctx.mode != "wash_and_verify":
            return "done"
        wc = ctx.cfg.wash
        done = len(ctx.wash.rounds)
        if ctx.result.dirt_map is None:
            return self._end(run, None, "no dirt map: the wash needs the cycle's dirt map (nothing was inspected)")
        if ctx.whole and not ctx.wash.scan_poses:
            if not ctx.stations.bin_poses:
                return self._end(run, None, "not washed: the whole-bin cycle measured no station's bin pose")
            # the poses the scan's plans were adjusted to; the base stands at the last station scanned
            ctx.wash.scan_poses = dict(ctx.stations.bin_poses)
            ctx.wash.parked = [r for r in ctx.stations.station_order if r in ctx.stations.bin_poses][-1]
        mesh = wash_mesh(ctx)
        dirty = _dirty_faces(ctx, mesh)
        if not dirty.any():
            seen = seen_fraction(ctx, mesh)
            if seen < wc.min_seen_fraction:
                why = (
                    f"unverified: no dirt seen, but the scan and re-inspections saw {seen:.0%} of the bin's area, "
                    f"below wash.min_seen_fraction {wc.min_seen_fraction:.0%}: the rest is not known clean"
                )
                return self._end(run, "incomplete", why, dirty, mesh)
            # the surfaces as the re-inspections leave them: CycleResult.coverage_by_surface says what clean covers
            ctx.result.coverage_by_surface = surface_fractions(
                mesh, np.flatnonzero(face_state(ctx.result.dirt_map, mesh.n_faces)[1])
            )
            verdict, gated = gate_verdict(
                "clean",
                ctx.result.coverage_by_surface,
                cast(Mapping[str, float], ctx.cfg.classifier.verdict.min_seen_fraction),
            )
            return self._end(run, verdict, gated, dirty, mesh)  # WashResult.seen_fraction: what clean covers
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
        ctx.wash.plan = plan
        ctx.wash.next_sweep = 0
        ctx.wash.next_view = 0
        ctx.wash.run = {"sweeps_run": 0, "passes_run": 0, "refused": [], "pictures": [], "replanned": []}
        ranks = wash_ranks(ctx)
        ctx.wash.run["ranks"] = ranks  # the plan's station k is ranks[k] (the base moves on this round)
        ctx.wash.station_sweeps = {}
        for k, rank in enumerate(ranks):
            mine = [sw for sw in plan.sweeps if sw.station == k]
            if mine:
                ctx.wash.station_sweeps[rank] = mine
        ctx.wash.queue = [r for r in ranks if r in ctx.wash.station_sweeps]
        ctx.wash.verify_queue = []
        ctx.wash.phase = "wash"
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
        assert ctx.identity.T_base_bin is not None and ctx.identity.bin_type is not None  # wash_mesh checked them
        poses = round_poses(ctx)
        req = WashPlanRequest(
            bin_type=ctx.identity.bin_type,
            stations=[PoseMsg.from_matrix(invert(T), "bin") for T in poses],
            q_start=state.joints,
            dirt_map=ctx.result.dirt_map,
            threshold=wc.threshold,
            margin_m=wc.margin_m,
            seed=ctx.params.seed,
            round=r,
        )
        reply, _ = run.call("planner", "wash_plan", req, WashPlanReply)
        return reply

    @staticmethod
    def _pictures(ctx: CycleContext, mesh: Any, plan: WashPlanReply, r: int) -> None:
        folder = picture_dir(ctx)
        if folder is None:
            return
        from cellctl.geometry.transforms import invert
        from cellctl.recording.dirt_map import draw_dirt_map
        from cellctl.washing.pictures import draw_wash_path

        assert ctx.identity.T_base_bin is not None
        name = ctx.identity.bin_type or "bin"
        poses = round_poses(ctx)
        view = _plan_view(plan, mesh.n_faces, [invert(T) for T in poses])
        before = draw_dirt_map(
            mesh, ctx.result.dirt_map or {}, folder / f"r{r}_before.png", f"{name} round {r}: before"
        )
        path = draw_wash_path(mesh, view, _spot_passes(plan), folder / f"r{r}_path.png", f"{name} round {r}:")
        ctx.wash.run["pictures"] = [before.name, path.name]  # in <cycle_id>.wash/: a replay's names match

    @staticmethod
    def _end(
        run: StepRun,
        verdict: str | None,
        reason: str | None,
        dirty: np.ndarray | None = None,
        mesh: Any = None,
        unwashable: list[dict[str, Any]] | None = None,
    ) -> str:
        ctx = run.ctx
        remaining = np.flatnonzero(dirty).tolist() if dirty is not None else []
        area = float(mesh.areas[dirty].sum()) if dirty is not None and mesh is not None else 0.0
        ctx.wash.result = WashResult(
            verdict=verdict,  # type: ignore[arg-type]
            reason=reason,
            rounds=list(ctx.wash.rounds),
            remaining_faces=remaining,
            remaining_m2=round(area, 6),
            unwashable=unwashable or [],
            seen_fraction=round(seen_fraction(ctx, mesh), 4) if mesh is not None and ctx.result.dirt_map else None,
            min_seen_fraction=ctx.cfg.wash.min_seen_fraction,
        )
        ctx.wash.plan = None
        if verdict is not None:
            ctx.result.verdict = verdict  # type: ignore[assignment]
        if verdict == "incomplete":
            ctx.result.reason = reason
        n = len(ctx.wash.rounds)
        run.event(
            "info" if verdict == "clean" else "warning",
            f"wash and verify: {verdict or 'no verdict'} after {n} round(s)" + (f" ({reason})" if reason else ""),
        )
        return "done"


class WashStation(Step):
    NAME = "wash_station"
    OUTCOMES = ("wash", "verify", "park")
    DESCRIPTION = "walk the round's stations: park at the next one to wash or re-inspect from, then wash or verify"
    READS = (
        "wash.phase",
        "wash.queue",
        "wash.verify_queue",
        "wash.plan",
        "wash.run",
        "wash.rounds",
        "wash.scan_poses",
        "wash.station_sweeps",
        "stations.station_order",
        "stations.plans",
        "identity.bin_type",
        "identity.T_base_bin",
    )
    CONSULTS = (*AT_STATION, "wash.parked", "scan.plan")
    WRITES = (
        "wash.phase",
        "wash.verify_queue",
        "wash.next_view",
        "wash.parked",
        "wash.station_sweeps",
        "stations.station_index",
        "stations.surface_index",
        "identity.approach",
        "identity.observation_index",
        "identity.identify_attempts",
    )

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        if ctx.wash.phase == "wash":
            if ctx.wash.queue:
                return "wash" if park_at(run, ctx.wash.queue[0], "wash from it") else "park"
            ctx.wash.phase = "verify"
            ctx.wash.verify_queue = verify_stations(ctx)
            ctx.wash.next_view = 0
        if ctx.wash.verify_queue and not park_at(run, ctx.wash.verify_queue[0], "re-inspect from it"):
            return "park"
        return "verify"


class Washing(Step):
    NAME = "washing"
    OUTCOMES = ("succeeded", "failed")
    DESCRIPTION = "run the station's wash sweeps on the robot, one request per sweep (a Hold resumes at the next)"
    READS = (
        "wash.plan",
        "wash.queue",
        "wash.rounds",
        "wash.run",
        "wash.station_sweeps",
        "wash.next_sweep",
        "stations.bin_poses",
        "identity.bin_type",
        "identity.T_base_bin",
    )
    WRITES = ("wash.next_sweep", "wash.run", "wash.queue", "wash.station_sweeps")

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        plan = ctx.wash.plan
        assert plan is not None  # READS wash_plan
        r = len(ctx.wash.rounds) + 1
        stats = ctx.wash.run
        rank = ctx.wash.queue[0] if ctx.wash.queue else None
        sweeps = ctx.wash.station_sweeps.get(rank)
        if sweeps is None:
            sweeps = self._replan(run, rank, r)
            ctx.wash.station_sweeps[rank] = sweeps
        where = f" at station {rank}" if rank is not None else ""
        for i in range(ctx.wash.next_sweep, len(sweeps)):
            sw = sweeps[i]
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
                # the reason's head names the sweep and the cause (the CycleResult has a size limit)
                stats["refused"].append({"sweep": i, "station": rank, "reason": str(err)[:120]})
                ctx.wash.next_sweep = i + 1
                continue
            stats["sweeps_run"] += reply.sweeps_run
            stats["passes_run"] += reply.passes_run
            stats["washed"] = sorted(set(stats.get("washed", [])) | set(sw.faces))
            ctx.wash.next_sweep = i + 1
        ctx.wash.next_sweep = 0
        if ctx.wash.queue:
            ctx.wash.queue.pop(0)
        run.event(
            "info",
            f"wash round {r}{where}: {len(sweeps)} sweeps; {stats['sweeps_run']} sweeps, {stats['passes_run']} "
            "passes run so far" + (f", {len(stats['refused'])} refused" if stats["refused"] else ""),
        )
        if not ctx.wash.queue and stats["sweeps_run"] == 0:
            first = stats["refused"][0]["reason"] if stats["refused"] else "none planned"
            n = sum(len(v) for v in ctx.wash.station_sweeps.values())
            raise WorkerFailed(f"robot ran none of the {n} wash sweeps (first: {first})", role="robot")
        return "succeeded"

    @staticmethod
    def _replan(run: StepRun, rank: int | None, r: int) -> list[Any]:
        """The base parked again at ``rank``: plan that station's share of the round (the target faces
        its sweeps of the round's plan sprayed) at the bin pose measured at this park."""
        from cellctl.geometry.transforms import invert

        ctx = run.ctx
        plan = ctx.wash.plan
        assert plan is not None and rank is not None and ctx.identity.bin_type is not None
        k = ctx.wash.run["ranks"].index(rank)
        # its share: the round's target faces under its sweeps' spot paths (within a footprint)
        mesh = wash_mesh(ctx)
        spots = [np.asarray(sw.spots, np.float64).reshape(-1, 3) for sw in plan.sweeps if sw.station == k]
        targets = np.asarray(plan.targets, np.int64)
        share: list[int] = []
        if spots and len(targets):
            P = np.concatenate(spots)
            d = np.linalg.norm(mesh.centroids[targets][:, None, :] - P[None, :, :], axis=2).min(axis=1)
            share = targets[d <= ctx.cfg.nozzle.footprint_m].tolist()
        state, _ = run.call("robot", "state", RobotStateRequest(), RobotState)
        req = WashPlanRequest(
            bin_type=ctx.identity.bin_type,
            stations=[PoseMsg.from_matrix(invert(ctx.stations.bin_poses[rank]), "bin")],
            q_start=state.joints,
            dirt_map={"seen_dirty": share},
            threshold=ctx.cfg.wash.threshold,
            margin_m=0.0,  # the share is of the round's targets: dilated already
            seed=ctx.params.seed,
            round=r,
        )
        reply, _ = run.call("planner", "wash_plan", req, WashPlanReply)
        ctx.log.write_json(
            topics.WASH_PLAN, "cellctl.WashPlan", {"round": r, "station": rank, "replanned": True, **reply.summary}
        )
        ctx.wash.run.setdefault("replanned", []).append(
            {"station": rank, "faces": len(share), "sweeps": len(reply.sweeps), "plan_s": reply.plan_s}
        )
        run.event(
            "info",
            f"wash round {r}: station {rank} parked again: its {len(share)} faces replanned at the measured pose "
            f"({len(reply.sweeps)} sweeps, {reply.plan_s:.1f} s)",
        )
        return list(reply.sweeps)
