"""Stage 6 of a whole-bin plan: per chosen station the timed tours (external then internal), the
station plans and the modelled cycle time.

Stations are independent (each starts and ends at home): they run on the workers
(:func:`run_tours`), each with its own random stream (seed, station's candidate, surface), so a
plan is the same whatever worker ran which station and in what order. A station's tour per
surface (:func:`_surface_tour`): the timed tour (:func:`~cellctl.planning.whole.timing._timed_tour`),
chains taken back where moves are unverified, the configurations refined and toured again, the
whole tour shifted by 2π where its ends get faster (:func:`_improve_tour`).
"""

from __future__ import annotations

import time
import uuid
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.planning.plan import Plan
from cellctl.planning.whole.chains import _readd_chains
from cellctl.planning.whole.connection import COARSE_STEP_RAD, Connected, chain_to_start
from cellctl.planning.whole.records import StationPlan
from cellctl.planning.whole.selection import exact_cover
from cellctl.planning.whole.state import StationEval, WholeState
from cellctl.planning.whole.timing import _end_s, _half_turned, _refine_configurations, _shift_tour, _timed_tour
from cellctl.surface import SURFACES

__all__ = ["prepare_tours", "run_tours", "summarize"]


class _NoSAType:
    """Selection's SA record for station shares (the annealing ran over all stations' pairs)."""

    iterations = 0
    accepted = 0
    loss_pct = 0.0


_NoSA: Any = _NoSAType()


def prepare_tours(ws: WholeState) -> None:
    """The tours' constants, and the chosen stations' configurations as evaluated: a tour run
    refines them in place (in process), and every run starts from these (the same plan on one
    worker or on several)."""
    timing = ws.params.timing
    ws.per_vp = timing.settle_s + timing.capture_s
    cam = ws.p0.camera  # a centred image sees the same faces turned by π about its optical axis
    ws.half_turn = abs(cam.cx - cam.width / 2.0) < 1e-6 and abs(cam.cy - cam.height / 2.0) < 1e-6
    ws.snap = {
        (id(e), surf): (c.reached.q.copy(), c.reached.T.copy(), c.reached.roll.copy())
        for e in ws.evals
        for surf, c in e.con.items()
    }
    ws.must_now = np.zeros(ws.off, dtype=bool)


def _restore(ws: WholeState) -> None:
    for e in ws.evals:
        for surf, c in e.con.items():
            q0, T0, r0 = ws.snap[(id(e), surf)]
            c.reached.q, c.reached.T, c.reached.roll = q0.copy(), T0.copy(), r0.copy()


@dataclass
class _At:
    """Where the arm is at a station between its tours: joints, known way home, modelled seconds so far."""

    q: NDArray[np.float64]
    hub: list[NDArray[np.float64]]
    cycle: float = 0.0


def station_tours(ws: WholeState, rank: int) -> tuple[StationPlan, dict[str, NDArray[np.int64]], dict[str, int]]:
    """Station ``rank``'s tours and plans; its (possibly chain-completed) picks and its counts."""
    e = ws.chosen_ev[rank]
    q_home, timing = ws.q_home, ws.params.timing
    mine: dict[str, int] = {}
    sels: dict[str, NDArray[np.int64]] = {}
    at = _At(q_home, [q_home, q_home])
    if e.identify is not None:
        at.cycle += timing.motion_s(np.array([q_home, e.identify[1]])) + ws.per_vp
        at.q = e.identify[1]
        at.hub = [at.q, q_home]
    plans: dict[str, Plan] = {}
    motion: dict[str, float] = {}
    for surf in ws.shared:
        plans[surf], motion[surf], sels[surf] = _surface_tour(ws, e, rank, surf, at, mine)
    at.cycle += timing.motion_s(np.array(at.hub))  # home before the base drives on
    plan_k = StationPlan(
        rank=rank,
        candidate=e.cand.index,
        angle_deg=e.cand.angle_deg,
        T_bin_base=e.cand.T_bin_base,
        identify_T_bin_cam=None if e.identify is None else e.identify[0],
        identify_q=None if e.identify is None else e.identify[1],
        identify_reason=e.identify_reason,
        plans=plans,
        motion_s=motion,
        cycle_s=at.cycle,
    )
    return plan_k, sels, mine


def _surface_tour(
    ws: WholeState, e: StationEval, rank: int, surf: str, at: _At, mine: dict[str, int]
) -> tuple[Plan, float, NDArray[np.int64]]:
    """Station ``rank``'s tour of ``surf`` from ``at`` (moved on to its end): the plan, its motion
    seconds and its share (chains taken back included); ``mine`` gets its counts."""
    from cellctl.planning import pipeline as pl
    from cellctl.planning.select import min_set_cover

    p0, q_home, timing, step = ws.p0, ws.q_home, ws.params.timing, ws.step
    picked, order_s = ws.picked, list(ws.shared)
    s, f_s, found, vis = e.setups[surf], e.filt[surf], e.found[surf], e.vis[surf]
    sel = picked[surf][rank]
    # the arm tucks home after the last surface scanned here; before, the next tour follows
    tuck = not any(len(picked[s2][rank]) for s2 in order_s[order_s.index(surf) + 1 :])
    rng = np.random.default_rng([p0.seed, 23, e.cand.index, SURFACES.index(surf)])
    q_now, hub = at.q, at.hub
    s = replace(s, q_start=q_now, rng=rng, params=replace(s.params, q_start=tuple(float(x) for x in q_now)))
    st = pl._Stages(None, False)
    hd = pl._Header(uuid.uuid4().hex[:12], ws.head["created"], ws.head["bin_type"], time.perf_counter())
    if len(sel) == 0:
        plan = pl.assemble(s, hd, st, f_s, found, vis, reason=f"station {rank}: no {surf} viewpoint was selected here")
        return plan, 0.0, sel
    con = e.con[surf]
    # the next surface's configurations here (its tour starts near one): what the shift aims at
    nxt = [s2 for s2 in order_s[order_s.index(surf) + 1 :] if len(picked[s2][rank])]
    after = e.con[nxt[0]].reached.q[picked[nxt[0]][rank]] if nxt else None
    tour_at = partial(
        _timed_tour,
        q_now,
        hub,
        con=con,
        q_home=q_home,
        world=s.world,
        timing=timing,
        rng=s.rng,
        max_step=COARSE_STEP_RAD,
        fine_step=step,
        tuck=tuck,
    )
    order, Dr, paths, secs_e, n_straight, unverified, stuck = _timed_tour(
        q_now, hub, sel, con, q_home, s.world, timing, s.rng, COARSE_STEP_RAD, step, tuck
    )
    if unverified:
        sel0 = sel
        sel, got = _readd_chains(sel, stuck, con.parent, (order, Dr, paths, secs_e, n_straight, unverified), tour_at)
        if len(sel) > len(sel0):
            mine["chain_readded"] = mine.get("chain_readded", 0) + len(sel) - len(sel0)
        order, Dr, paths, secs_e, n_straight, unverified = got
    q_chain = con.reached.q.copy()  # the chains home are straight between these configurations
    tour = (order, Dr, paths, secs_e, n_straight, unverified)
    order, Dr, paths, secs_e, n_straight, unverified = _improve_tour(
        ws, e, s, con, sel, tour, tour_at, q_now, after, mine
    )
    Dr = np.zeros_like(Dr)
    for a, b, pth in zip(order[:-1], order[1:], paths, strict=True):
        Dr[a, b] = Dr[b, a] = float(np.linalg.norm(np.diff(pth, axis=0), axis=1).sum())
    approaches = tuple(None if len(pth) == 2 else pth for pth in paths)
    n_nodes = len(sel) + 1
    tour_counts = {
        "matrix_pairs": n_nodes * (n_nodes - 1) // 2,
        "matrix_straight": int(n_straight),
        "tour_failed_edges": unverified,
    }
    mine["unverified_moves"] = mine.get("unverified_moves", 0) + unverified
    selection = pl.Selection(sel, sel, _NoSA)
    allowed = np.ones(vis.C.shape[1], dtype=bool)
    ordered = pl.Ordered(selection, pl.Tour(order, Dr, approaches, tour_counts), allowed, 0)
    cover = ws.station_covers.get((e.cand.index, surf))  # the same for every tour run of the station
    if cover is None:
        n_opt, proven, secs = min_set_cover(vis.C[:, allowed], min(2.0, p0.cover_time_limit_s))
        cover = pl.Cover(n_opt, proven, secs)
    plan = replace(pl.assemble(s, hd, st, f_s, found, vis, ordered, cover), job_id=ws.job_id)
    mt = float(sum(secs_e))
    at.cycle += mt + len(sel) * ws.per_vp
    last = int(sel[order[-1] - 1])
    at.q = found.reached.q[last]
    if np.allclose(at.q, q_chain[last]):
        at.hub = [*chain_to_start(last, con.parent, q_chain), q_home]
    else:  # a new configuration at the end is one whose straight motion home was checked
        at.hub = [at.q, q_home]
    return plan, mt, sel


def _improve_tour(
    ws: WholeState,
    e: StationEval,
    s: Any,
    con: Connected,
    sel: NDArray[np.int64],
    tour: tuple[Any, ...],
    tour_at: Any,
    q_now: NDArray[np.float64],
    after: NDArray[np.float64] | None,
    mine: dict[str, int],
) -> tuple[Any, ...]:
    """A timed tour of ``sel`` refined: each viewpoint's configuration, a second order over those
    (``tour_at``: :func:`_timed_tour` from ``q_now``), the whole tour a 2π turn over; the reached
    configurations (and half-turned cameras' poses) of ``con`` updated in place. The tour
    ``(order, Dr, paths, seconds, straight pairs, unverified)``."""
    from cellctl.planning.reach import _rz

    robot, q_home, timing, step = ws.robot, ws.q_home, ws.params.timing, ws.step
    order, Dr, paths, secs_e, n_straight, unverified = tour
    # seconds from the tour's end on: home (it tucks), else to the next surface's nearest
    end_t = partial(_end_s, sel=sel, parent=con.parent, q_home=q_home, timing=timing, after=after)
    nodes = np.vstack([q_now[None], con.reached.q[sel]])
    new_q, paths, secs_e, n_changed = _refine_configurations(
        nodes, order, paths, secs_e, robot, s.world, e.accept, timing, q_home, step, ws.half_turn
    )
    if n_changed and len(sel) > 2:  # a second order over the refined configurations
        # 2-opt from the refined tour's order (no ant colony, no second refinement: ~CPU)
        o2, Dr2, p2, t2, ns2, u2, _stuck2 = tour_at(sel, q_sel=new_q[1:], init=order)
        Q0 = con.reached.q
        t_new = sum(t2) + end_t(o2, new_q, Q=Q0)
        if u2 <= unverified and t_new < sum(secs_e) + end_t(order, new_q, Q=Q0) - 1e-6:
            order, Dr, paths, secs_e, n_straight, unverified = o2, Dr2, p2, t2, ns2, u2
            n_changed = int(np.any(np.abs(new_q[1:] - con.reached.q[sel]) > 0, axis=1).sum())
            mine["retoured"] = mine.get("retoured", 0) + 1
    # the whole tour a 2π turn over on the ±2π joints where its move in and out are faster
    end_now = end_t(order, new_q, Q=con.reached.q)
    shifted = _shift_tour(q_now, new_q, order, paths, secs_e, end_now, after, robot, s.world, timing, q_home, step)
    if shifted is not None:
        new_q, order, paths, secs_e = shifted
        mine["tour_shifted"] = mine.get("tour_shifted", 0) + 1
    turned = _half_turned(robot, con.reached.q[sel], new_q[1:])
    if turned.any():  # the camera turned by π about its axis: the same view, its pose and roll
        ids = sel[turned]
        con.reached.T[ids] = con.reached.T[ids] @ _rz(np.pi)
        con.reached.roll[ids] = np.mod(con.reached.roll[ids] + 2 * np.pi, 2 * np.pi) - np.pi
        mine["half_turned"] = mine.get("half_turned", 0) + int(turned.sum())
    con.reached.q[sel] = new_q[1:]
    mine["reconfigured"] = mine.get("reconfigured", 0) + n_changed
    return order, Dr, paths, secs_e, n_straight, unverified


def _job(ws: WholeState, k: int) -> Any:
    """The exact cover (``k`` < 0: it only reads the selection, the tours do not change what it
    covers; handed out first, its MILP has its own time limit) or station ``k``'s tours."""
    return exact_cover(ws, ws.must_now) if k < 0 else station_tours(ws, k)


def _keep_covers(ws: WholeState, jobs_out: list[Any]) -> None:
    """Per (station, surface) the single-station exact cover over all its reachable candidates: it
    does not depend on the selection, so a budget's tour runs take it from the first run (kept in
    ``ws``, where the forked workers of the next run inherit it)."""
    from cellctl.planning import pipeline as pl

    for plan_k, _sels, _mine in jobs_out:
        for surf, p in plan_k.plans.items():
            if p.viewpoints and p.counts.optimal_cover is not None:
                ws.station_covers.setdefault(
                    (plan_k.candidate, surf),
                    pl.Cover(
                        p.counts.optimal_cover,
                        bool(p.stage_counts.optimal_cover_proven),
                        float(p.times_s.exact_cover_s or 0.0),
                    ),
                )


def run_tours(ws: WholeState, with_exact: bool, reuse: dict[str, Any] | None = None) -> dict[str, Any]:
    """Tours of ``ws.chosen_ev`` / ``ws.picked`` as they stand: stations, shares after chain re-adds, figures.

    ``reuse``: a run of the same stations whose tours are taken for every station whose share
    of ``picked`` is the same (a station's tours depend on its own share only)."""
    from cellctl.planning.parallel import fork_map

    _restore(ws)
    picked = ws.picked
    ranks = list(range(len(ws.chosen_ev)))
    if reuse is not None:
        ranks = [k for k in ranks if any(not np.array_equal(picked[s][k], reuse["picked"][s][k]) for s in picked)]
    done_jobs = fork_map(partial(_job, ws), [-1, *ranks] if with_exact else ranks, ws.workers)
    exact = done_jobs[0] if with_exact else None
    got = dict(zip(ranks, done_jobs[1:] if with_exact else done_jobs, strict=True))
    jobs_out = [got[k] if k in got else reuse["jobs"][k] for k in range(len(ws.chosen_ev))]  # type: ignore[index]
    _keep_covers(ws, jobs_out)
    return summarize(ws, jobs_out, picked, ws.chosen_ev, exact, ws.sel_counts)


def summarize(
    ws: WholeState,
    jobs_out: list[Any],
    selection: dict[str, list[NDArray[np.int64]]],
    chosen_ev: list[StationEval],
    exact: Any,
    sel_counts: dict[str, int],
) -> dict[str, Any]:
    """The figures of one tour per station (``jobs_out``: station_tours' answers in rank order)."""
    from cellctl.planning.stations import base_move_s

    stations: list[StationPlan] = []
    shares = {surf: list(v) for surf, v in selection.items()}
    tour_counts: dict[str, int] = {}
    for plan_k, sels, mine in jobs_out:
        stations.append(plan_k)
        for surf, sel in sels.items():
            shares[surf][plan_k.rank] = sel
        for key, v in mine.items():
            tour_counts[key] = tour_counts.get(key, 0) + v
    seen_m2: dict[str, tuple[float, int]] = {}
    for surf in ws.shared:  # a station share may have taken its chains back (above)
        seen_f = np.zeros(len(ws.areas[surf]), dtype=bool)
        for k, e in enumerate(chosen_ev):
            if len(shares[surf][k]):
                seen_f |= e.vis[surf].C[:, shares[surf][k]].any(axis=1)
        seen_m2[surf] = (float(ws.areas[surf][seen_f].sum()), int(sum(len(x) for x in shares[surf])))
    moves = sum(
        base_move_s(ws.cands, a.candidate, b.candidate, ws.params.stations)
        for a, b in zip(stations[:-1], stations[1:], strict=True)
    )
    return {
        "stations": stations,
        "jobs": jobs_out,
        "exact": exact,
        "picked": shares,
        "counts": tour_counts,
        "seen": seen_m2,
        "moves": float(moves),
        "cycle": float(sum(s.cycle_s for s in stations) + moves),
        "chosen_ev": chosen_ev,
        "selection": selection,
        "sel_counts": dict(sel_counts),
    }
