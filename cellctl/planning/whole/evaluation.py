"""Stages 2 and 3 of a whole-bin plan: evaluate the candidate stations, choose the fewest.

Per usable candidate station: the distance filter, reachability (IK + collision, parking
robustness), connection (:func:`cellctl.planning.whole.connection.connect`), visibility and the
identification pose (:func:`_identification`). Each evaluation reads only the shared set-up, so
they run on forked workers (:func:`evaluate_all`). The stations are chosen by a set cover over
their seen faces (:func:`cellctl.planning.stations.choose_stations`) and visited around the bin
(:func:`_ring_order`).
"""

from __future__ import annotations

from functools import partial
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.catalog import BinType
from cellctl.geometry.transforms import invert
from cellctl.planning.collision import PlanningWorld
from cellctl.planning.reach import Reached
from cellctl.planning.robot import RobotModel
from cellctl.planning.stations import Candidate
from cellctl.planning.whole.connection import COARSE_STEP_RAD, connect, wrap_window
from cellctl.planning.whole.state import StationEval, WholeState

__all__ = ["evaluate_and_choose", "note_reachable"]


def _identification(
    bin_type: BinType | None,
    world: PlanningWorld,
    robot: RobotModel,
    T_base_bin: NDArray[np.float64],
    q_home: NDArray[np.float64],
    step: float,
) -> tuple[tuple[NDArray[np.float64], NDArray[np.float64]] | None, str | None]:
    """The first observation pose (looking at the board) the arm reaches from home by a straight free motion."""
    if bin_type is None:
        return None, "no bin type (a mesh without a catalog board): the bin pose comes from the cycle's first station"
    from cellctl.planning.reach import wrap_towards
    from cellctl.sim.scene import n_observation_poses, observation_T_bin_cam

    for k in range(n_observation_poses()):
        T = observation_T_bin_cam(bin_type, k)
        # each joint's 2π turn nearest home, nearest first: what the arm takes at run time (its IK
        # wraps towards the current joints, home; cellctl.geometry.robot_model.ik). IK's own (−π, π]
        # put the base joint 5.6 rad from home's π where its turn is 0.7 rad away (case study seed 5)
        S = wrap_towards(robot.ik_cam(T_base_bin @ T), q_home, robot)
        if len(S) == 0:
            continue
        S = S[np.argsort(np.linalg.norm(S - q_home, axis=1))]
        S = S[world.robot_free(S)]
        if len(S) == 0:
            continue
        moves = world.motion_free(np.repeat(q_home[None], len(S), axis=0), S, step)
        if moves.any():
            return (T, S[int(np.flatnonzero(moves)[0])]), None
    return None, (
        "the board is not visible from this station (no observation pose reachable by a free motion): "
        "the bin pose is carried over from the previous station by the base's move"
    )


def station_world(ws: WholeState, c: Candidate, margin: float) -> tuple[PlanningWorld, Any]:
    """The planning world and the parking-robustness test at ``c`` with this clearance."""
    from dataclasses import replace

    from cellctl.planning.reach import robust_acceptor

    world = PlanningWorld(ws.mesh, ws.robot, c.T_bin_base, margin=margin)
    return world, robust_acceptor(ws.mesh, ws.robot, c.T_bin_base, replace(ws.p0, margin=margin))


def station_setup(ws: WholeState, c: Candidate, surf: str, world: PlanningWorld) -> Any:
    """The single-station pipeline's set-up (:class:`cellctl.planning.pipeline.Setup`) at ``c`` for ``surf``."""
    from dataclasses import replace

    from cellctl.planning import pipeline as pl

    filt, sf, rng = ws.shared[surf]
    return pl.Setup(
        mesh=ws.mesh,
        robot=ws.robot,
        params=replace(ws.p0, surface=surf),
        T_bin_base=c.T_bin_base,
        T_base_bin=invert(c.T_bin_base),
        q_start=ws.q_home,
        surf_faces=sf,
        world=world,
        rays=ws.rays,
        rng=rng,  # the plan's stream per surface: the tours draw from it station after station
    )


def attach(ws: WholeState, ev: StationEval) -> StationEval:
    """Give an evaluation (from a worker: plain arrays) its world, robustness test and set-ups."""
    world, ev.accept = station_world(ws, ev.cand, ev.margin)
    for surf in ev.filt:
        ev.setups[surf] = station_setup(ws, ev.cand, surf, world)
    return ev


def evaluate(ws: WholeState, c: Candidate, thin: int = 1) -> StationEval:
    """Reach, connection and visibility at ``c``: plain arrays only (it may run in a worker
    process; :func:`attach` adds the world and set-ups where they are used).

    ``thin`` > 1, the estimate that ranks candidates: every thin-th seed direction only, no
    identification pose. (Without the parking-robustness test as well it cost about the same
    and misled the choice: case study seed 0 took an inner station whose views do not survive
    parking error, external 89.7 % of the bound.)
    """
    from cellctl.planning import pipeline as pl
    from cellctl.planning.filters import distance_filter

    p0, robot, q_home = ws.p0, ws.robot, ws.q_home
    ev = StationEval(c, margin=p0.margin)
    T_base_bin = invert(c.T_bin_base)
    world = PlanningWorld(ws.mesh, robot, c.T_bin_base, margin=p0.margin)
    if thin == 1:
        ev.identify, why = _identification(ws.bin_type, world, robot, T_base_bin, q_home, ws.step)
        ev.identify_reason = why
        if ev.identify is None and ws.params.odometry_m > 0:
            # No board here: the cycle adjusts the plan to the pose carried by the base's odometry,
            # whose error it cannot see, so every configuration (and each one the robustness check
            # re-solves for a parking error) keeps that much more clearance. The plan keeps the
            # margin it is checked with at lookup.
            ev.margin = p0.margin + ws.params.odometry_m
    world, accept = station_world(ws, c, ev.margin)
    reached: dict[str, tuple[Any, Any, Any, Any, Any]] = {}
    for surf, (filt, _sf, _rng) in ws.shared.items():
        s = station_setup(ws, c, surf, world)
        p = s.params
        near = distance_filter(filt.vp, c.T_bin_base[:3, 3], p.max_reach)
        keep = np.flatnonzero(near & (filt.vp.seed % thin == 0))
        vp = filt.vp.subset(keep)
        f_s = pl.Filtered(
            vp,
            filt.generated,
            filt.seeds,
            filt.after_height,
            len(keep),
            filt.after_occlusion,
            filt.after_camera_collision,
        )
        st = pl._Stages(None, False)
        st.start("reachability", "reachability")
        if len(vp) == 0:
            found = pl.Reachability(
                Reached(np.zeros(0, np.int64), np.zeros((0, 4, 4)), np.zeros((0, 6)), np.zeros(0), 0, 0), 0, 0
            )
            st.end()
        else:
            found = pl.reach(s, vp, st)
        reached[surf] = (s, vp, f_s, st, found)
    # one 2π window per ±2π joint for all the station's configurations (both surfaces): no
    # full turns of a joint between neighbours, nor between the surfaces' tours
    wrap = wrap_window(np.vstack([r[4].reached.q for r in reached.values()]), robot, q_home)
    for surf, (s, vp, f_s, st, found) in reached.items():
        found.reached.q[:] = wrap(found.reached.q)
        con = connect(
            vp, found.reached, robot, world, T_base_bin, q_home, s.params.n_roll, accept, COARSE_STEP_RAD, wrap
        )
        ev.con[surf] = con
        ev.replaced += con.replaced
        ev.unconnected += con.unconnected
        found = pl.Reachability(con.reached, found.planner_queries, found.rrtconnect_fallbacks)
        vis = pl.measure(s, found.reached, st)
        ev.filt[surf], ev.found[surf], ev.vis[surf] = f_s, found, vis
        seen = vis.C.any(axis=1) if vis.C.shape[1] else np.zeros(len(s.surf_faces), dtype=bool)
        ev.seen[surf] = cast(NDArray[np.bool_], seen)
    return ev


def evaluate_all(ws: WholeState, cs: list[Candidate], thin: int = 1) -> list[StationEval]:
    """Every candidate's evaluation, on ``ws.workers`` processes (the same answer on one)."""
    from cellctl.planning.parallel import fork_map

    return [attach(ws, e) for e in fork_map(partial(evaluate, ws, thin=thin), cs, ws.workers)]


def evaluate_and_choose(ws: WholeState) -> list[int]:
    """Evaluate the usable candidates and choose stations (fewest first); the chosen ones' indices
    in ``ws.evals``. Sets ``ws.areas``, ``ws.bounds``, ``ws.evals``, ``ws.scores``.

    By default every candidate is evaluated in full. With estimate_thin > 1 (reach + connection
    are ~3/4 of the planning time and most candidates are not chosen) every candidate is first
    evaluated on every estimate_thin-th seed direction only (an estimate from below, alike for
    all), the stations are chosen over those masks, and only the chosen ones (± one station) are
    evaluated in full; the rule runs again over those.
    """
    from cellctl.planning.stations import choose_stations

    params, usable = ws.params, ws.usable
    ws.areas = areas = {s: ws.mesh.areas[ws.shared[s][1]] for s in ws.shared}
    ws.bounds = bounds = {s: ws.surfaces[s].bound_m2 for s in ws.shared}
    if params.estimate_thin > 1 and len(usable) > params.stations.max_stations:
        estimate = [e.seen for e in evaluate_all(ws, usable, params.estimate_thin)]
        per_size: list[tuple[int, ...]] = []
        first, _ = choose_stations(estimate, areas, bounds, params.stations, best_per_size=per_size)
        # the estimate's choice and its best subsets one station smaller and larger: the full masks
        # decide (the rule again, below) among those, so a thin estimate neither adds nor saves a
        # station the full evaluation would not
        k = len(first)
        first = sorted({*first, *(per_size[k - 2] if k > 1 else ()), *(per_size[k] if k < len(per_size) else ())})
        done = dict(zip(first, evaluate_all(ws, [usable[i] for i in first]), strict=True))
        ws.say("stations", 1.0)
        # the same rule again over the full masks of those: a station the thin estimate took for
        # a gain it does not make in full (a thin estimate sees less from each station) is dropped
        ids = sorted(done)
        sub, ws.scores = choose_stations([done[i].seen for i in ids], areas, bounds, params.stations)
        chosen = [ids[k] for k in sub]
    else:  # every candidate in full (the default), choose on full masks
        done = dict(enumerate(evaluate_all(ws, usable)))
        ws.say("stations", 1.0)
        chosen, ws.scores = choose_stations([done[i].seen for i in sorted(done)], areas, bounds, params.stations)
    ws.evals = [done[i] for i in sorted(done)]
    pos = {i: k for k, i in enumerate(sorted(done))}
    return [pos[i] for i in chosen]


def note_reachable(ws: WholeState, chosen: list[int]) -> bool:
    """Count the evaluation and set each surface's arm-aware bound; False when no chosen station sees the bin."""
    from dataclasses import replace

    evals = ws.evals
    ws.counts["stations_evaluated"] = len(evals)
    ws.counts["replaced_unconnected"] = sum(e.replaced for e in evals)
    ws.counts["unconnected_directions"] = sum(e.unconnected for e in evals)
    for surf in ws.shared:
        m = np.zeros(len(ws.areas[surf]), dtype=bool)
        for e in evals:
            m |= e.seen[surf]
        ws.surfaces[surf] = replace(ws.surfaces[surf], reachable_m2=float(ws.areas[surf][m].sum()))
    return bool(chosen) and any(evals[i].seen[s].any() for i in chosen for s in ws.shared)


def _ring_order(evs: list[StationEval]) -> list[StationEval]:
    """Chosen stations around the bin by direction, from one that sees the board, the shorter way round."""
    if len(evs) <= 1:
        return evs
    start = next((e for e in sorted(evs, key=lambda e: e.cand.index) if e.identify is not None), evs[0])
    a0 = start.cand.angle_deg

    def span(direction: int) -> tuple[float, list[StationEval]]:
        def rel(e: StationEval) -> float:
            return round(((e.cand.angle_deg - a0) * direction) % 360.0, 6)

        ordered = sorted(evs, key=lambda e: (rel(e), e is not start, e.cand.ring))
        return rel(ordered[-1]), ordered

    a, b = span(1), span(-1)
    return a[1] if a[0] <= b[0] else b[1]
