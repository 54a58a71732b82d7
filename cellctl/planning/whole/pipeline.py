"""The whole-bin pipeline: :func:`plan_whole` as a sequence of stages over one :class:`WholeState`.

=====  =====================================================  ==========================================
stage  what                                                   where
=====  =====================================================  ==========================================
0      set-up: candidate stations, ray caster, plan header    :func:`start`
1      per surface: seeds, viewpoints, filters, upper bound   :func:`bound_surfaces`
2, 3   evaluate candidate stations, choose the fewest         :mod:`~cellctl.planning.whole.evaluation`
4      viewpoint selection over the chosen stations           :mod:`~cellctl.planning.whole.selection`
5      the exact (station, viewpoint) cover's columns         :mod:`~cellctl.planning.whole.selection`
6      timed tours per station, station plans, cycle time     :mod:`~cellctl.planning.whole.tours`
7      over the cycle budget: fewer stations, trim            :mod:`~cellctl.planning.whole.budget`
8      the plan record                                        :func:`finish`
=====  =====================================================  ==========================================
"""

from __future__ import annotations

import resource
import time
import uuid
from dataclasses import replace

import numpy as np

from cellctl.geometry.catalog import BinMesh, BinType
from cellctl.geometry.transforms import invert
from cellctl.planning.collision import PlanningWorld
from cellctl.planning.raycast import RayCaster
from cellctl.planning.robot import RobotModel
from cellctl.planning.whole.budget import meet_budget
from cellctl.planning.whole.evaluation import _ring_order, evaluate_and_choose, note_reachable
from cellctl.planning.whole.records import ProgressFn, SurfaceSummary, WholeParams, WholePlan
from cellctl.planning.whole.selection import exact_cover_columns, must_of, select_viewpoints
from cellctl.planning.whole.state import WholeState
from cellctl.planning.whole.tours import prepare_tours, run_tours
from cellctl.surface import SURFACES

__all__ = ["bound_surfaces", "finish", "plan_whole", "start"]


def plan_whole(
    mesh: BinMesh,
    params: WholeParams,
    robot: RobotModel,
    *,
    bin_type: BinType | None = None,
    progress: ProgressFn | None = None,
    job_id: str | None = None,
) -> WholePlan:
    """Plan the whole bin: stations, both surfaces, connected viewpoints, timed tours.

    Nothing to plan is an answer, not an exception: the plan's ``reason`` (and each surface's
    and station's) says why (no usable station, a surface without faces, nothing visible …).

    ``job_id`` (the planner worker's job) is recorded in every station plan.

    Raises:
        PlanningError: bad parameters.
    """
    params.check()
    ws = start(mesh, params, robot, bin_type, progress, job_id)
    t = time.perf_counter()
    bound_surfaces(ws)
    t = ws.tick("generate_filter_bound", t)
    ws.say("generate_filter", 1.0)
    if not ws.usable:
        return _empty(ws, "no candidate station is usable: " + "; ".join(f"{c.name}: {c.reason}" for c in ws.cands))
    if not ws.shared:
        return _empty(ws, "no surface can be planned: " + "; ".join(f"{k}: {v.reason}" for k, v in ws.surfaces.items()))
    chosen = evaluate_and_choose(ws)
    t = ws.tick("stations", t)
    if not note_reachable(ws, chosen):
        return _empty(
            ws,
            f"no station sees the bin: none of the {len(ws.usable)} usable stations reaches a viewpoint that "
            "properly sees a face (is the bin within the arm's reach of its stations?)",
        )
    ws.chosen_ev = _ring_order([ws.evals[i] for i in chosen])
    t = ws.tick("choose_stations", t)
    ws.floors = {s: params.min_bound_pct.get(s, 0.0) / 100.0 * ws.bounds[s] for s in ws.shared}
    ws.picked, ws.greedy_n, ws.sel_counts, _ = select_viewpoints(ws, ws.chosen_ev)
    ws.counts.update(ws.sel_counts)
    t = ws.tick("selection", t)
    exact_cover_columns(ws)
    t = ws.tick("exact_cover", t)
    prepare_tours(ws)
    ws.must_now = must_of(ws, ws.chosen_ev, ws.picked)
    ws.res = run_tours(ws, True)
    ws.exact = ws.res["exact"]
    meet_budget(ws)
    return finish(ws, t)


def start(
    mesh: BinMesh,
    params: WholeParams,
    robot: RobotModel,
    bin_type: BinType | None,
    progress: ProgressFn | None,
    job_id: str | None,
) -> WholeState:
    """The plan's state: clocks, the plan's header, the candidate stations, the ray caster."""
    from cellctl.planning.parallel import default_workers
    from cellctl.planning.stations import candidate_stations
    from cellctl.sim.motion import STEP_RAD

    workers = params.workers or default_workers()
    t0 = time.perf_counter()
    cpu0 = time.process_time()
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    p0 = params.plan
    q_home = np.asarray(p0.q_start if p0.q_start is not None else robot.q_home, dtype=np.float64)
    head = dict(
        plan_id=uuid.uuid4().hex[:12],
        created=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        bin_type=bin_type.name if bin_type is not None else mesh.name,
        mesh_sha256=mesh.sha256,
        robot_model_id=robot.model_id(),
        params=params,
    )
    cands = candidate_stations(mesh, bin_type, params.stations)
    usable = [c for c in cands if c.reason is None]
    ws = WholeState(
        mesh=mesh,
        params=params,
        robot=robot,
        bin_type=bin_type,
        progress=progress,
        job_id=job_id,
        workers=workers,
        t0=t0,
        cpu0=cpu0,
        ru0=ru0,
        step=STEP_RAD,  # the sim arm's own motion-check step: a motion called free here is free there
        q_home=q_home,
        head=head,
        cands=cands,
        usable=usable,
        rays=RayCaster(mesh.vertices, mesh.faces),
    )
    ws.counts.update({"candidates": len(cands), "usable_candidates": len(usable)})
    return ws


def bound_surfaces(ws: WholeState) -> None:
    """Stage 1, per surface: the single-station pipeline's seeds, viewpoints and filters once (no
    distance filter: they do not depend on the base) and the **upper bound**, the area properly
    visible from any filtered camera pose (no arm). Sets ``ws.shared`` and ``ws.surfaces``."""
    from cellctl.planning import pipeline as pl
    from cellctl.planning.visibility import measurability

    mesh, robot, p0, q_home = ws.mesh, ws.robot, ws.p0, ws.q_home
    ref = ws.usable[0].T_bin_base if ws.usable else ws.cands[0].T_bin_base
    for surf in ws.params.surfaces:
        sf = np.flatnonzero(mesh.surface_mask(surf))
        area = float(mesh.areas[sf].sum())
        if len(sf) == 0:
            ws.surfaces[surf] = SurfaceSummary(0.0, 0.0, 0.0, 0, reason=f"the mesh has no {surf} faces")
            continue
        p = replace(p0, surface=surf, max_reach=1.0e3)
        s = pl.Setup(
            mesh=mesh,
            robot=robot,
            params=p,
            T_bin_base=ref,
            T_base_bin=invert(ref),
            q_start=q_home,
            surf_faces=sf,
            world=PlanningWorld(mesh, robot, ref, margin=p.margin),
            rays=ws.rays,
            rng=np.random.default_rng([p0.seed, SURFACES.index(surf)]),
        )
        st = pl._Stages(None, False)
        st.start("generate_filter", "generate+filter")
        filt = pl.generate_and_filter(s, st)
        if len(filt.vp) == 0:
            ws.surfaces[surf] = SurfaceSummary(area, 0.0, 0.0, 0, reason=f"no {surf} viewpoint survived the filters")
            continue
        C_all = measurability(filt.vp.T, mesh, sf, p.camera, ws.rays)
        bound = float(mesh.areas[sf][C_all.any(axis=1)].sum())
        if bound <= 0:
            ws.surfaces[surf] = SurfaceSummary(
                area, 0.0, 0.0, 0, reason=f"no {surf} face is properly visible from any camera pose"
            )
            continue
        ws.shared[surf] = (filt, sf, s.rng)
        ws.surfaces[surf] = SurfaceSummary(area, bound, 0.0, 0)


def _empty(ws: WholeState, reason: str) -> WholePlan:
    """The plan with no stations: ``reason`` says why."""
    return WholePlan(
        **ws.head,
        stations=(),
        candidates=tuple(ws.cands),
        surfaces=ws.surfaces,
        counts=ws.counts,
        exact=None,
        station_scores={},
        base_moves_s=0.0,
        cycle_time_s=0.0,
        times_s=ws.close_times(),
        reason=reason,
    )


def finish(ws: WholeState, t: float) -> WholePlan:
    """The plan record from the tour run kept (``ws.res``); ``t``: when the tours began (their seconds)."""
    res, counts, surfaces = ws.res, ws.counts, ws.surfaces
    stations = res["stations"]
    for key, v in res["counts"].items():
        counts[key] = counts.get(key, 0) + v
    for surf in ws.shared:
        seen_v, n_vp = res["seen"][surf]
        surfaces[surf] = replace(surfaces[surf], seen_m2=seen_v, viewpoints=n_vp)
    moves = res["moves"]
    ws.tick("tours", t)  # the exact cover's MILP included (it runs beside the tours)
    counts["dropped_unconnected"] = 0
    counts["stations"] = len(stations)
    counts.update({f"greedy_{k}": v for k, v in ws.greedy_n.items()})
    # no reason: a first station's missing board is said in its identify_reason
    return WholePlan(
        **ws.head,
        stations=tuple(stations),
        candidates=tuple(ws.cands),
        surfaces=surfaces,
        counts=counts,
        exact=ws.exact,
        station_scores=ws.scores,
        base_moves_s=float(moves),
        cycle_time_s=float(sum(s.cycle_s for s in stations) + moves),
        times_s=ws.close_times(),
        reason=None,
    )
