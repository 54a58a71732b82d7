"""One station's wash sweeps: the inspection planner's stages with the nozzle for the camera.

:func:`_station` runs, for the face points still short of passes: the raster waypoints near them
(:func:`_waypoints`), nozzle poses through the planner's filters and the lance's (:func:`_filtered`),
reachability and connection to home (:func:`_reached`), the faces each waypoint sprays
(:func:`_sprayed`), sweeps as runs of a raster line (:func:`_candidate_sweeps`), a greedy multi-cover
(:func:`_multi_cover`) and the tour over the chosen sweeps (:func:`_tour`).
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.catalog import BinMesh
from cellctl.geometry.transforms import invert
from cellctl.planning.robot import RobotModel
from cellctl.washing.nozzle import NozzleModel
from cellctl.washing.plan.budget import _Budget
from cellctl.washing.plan.records import MAX_REACH_M, MAX_SWEEP_STEP_RAD, Sweep, WashParams
from cellctl.washing.plan.seeds import _FacePoints, _lance_free, _Line, _nozzle_poses
from cellctl.washing.targets import Facet

__all__: list[str] = []


class _Seen:
    """Per raster waypoint, the furthest stage any station got it to (for the unwashable reasons)."""

    def __init__(self, n: int) -> None:
        self.filtered = np.zeros(n, bool)
        self.reached = np.zeros(n, bool)


def _add(times: dict[str, float], key: str, t0: float) -> None:
    times[key] = times.get(key, 0.0) + time.perf_counter() - t0


@dataclass
class _Waypoints:
    """A station's live raster waypoints: positions, seed faces, jet normals, raster line, index among
    all the plan's waypoints, and whether the internal rule may aim it (not a tilted residue candidate)."""

    live: list[int]
    pts: NDArray[np.float64]
    seed_faces: NDArray[np.int64]
    nrm: NDArray[np.float64]
    line_of: NDArray[np.int64]
    wp_all: NDArray[np.int64]
    extra: NDArray[np.bool_]


def _station(
    mesh: BinMesh,
    facets: list[Facet],
    lines: list[_Line],
    T_bin_base: NDArray[np.float64],
    need: NDArray[np.int64],
    fp: _FacePoints,
    nozzle: NozzleModel,
    robot: RobotModel,
    p: WashParams,
    q0: NDArray[np.float64],
    rays: Any,
    seen: _Seen,
    times: dict[str, float],
    counts: Counter[str],
    budget: _Budget | None = None,
) -> list[tuple[Sweep, NDArray[np.int64], bool]]:
    """One station's sweeps for the face points still in ``need``, in tour order: each with the
    points under it and whether the straight transit to it is collision-free. With a ``budget``, none
    (counted under its key) when its reachability stage would not fit."""
    from cellctl.planning.collision import PlanningWorld

    # seeds → nozzle poses → the planner's filters; only lines over faces still needing passes
    t = time.perf_counter()
    wp = _waypoints(facets, lines, need, fp, nozzle)
    if wp is None:
        return []
    tool = nozzle.robot_with_nozzle(robot)
    world = PlanningWorld(mesh, tool, T_bin_base, margin=p.margin)
    filtered = _filtered(mesh, wp, T_bin_base, nozzle, world, rays, counts)
    seen.filtered[wp.wp_all[filtered.seed]] = True
    _add(times, "generate_filter", t)

    t = time.perf_counter()
    units = len(filtered) * p.n_roll  # what reachability costs: IK and collision checks per pose and roll
    if budget is not None and not budget.rate.fits(units, time.process_time() - budget.cpu0):
        counts[budget.key] += 1
        return []
    c = time.process_time()
    reached = _reached(filtered, tool, world, T_bin_base, p, counts)
    if budget is not None:
        budget.rate.add(units, time.process_time() - c)
    _add(times, "reachability", t)
    wp_q = np.full((len(wp.pts), 6), np.nan)
    wp_T = np.full((len(wp.pts), 4, 4), np.nan)
    if reached is not None and len(reached.index):
        s_idx = filtered.seed[reached.index]
        wp_q[s_idx], wp_T[s_idx] = reached.q, reached.T
    ok_wp = np.isfinite(wp_q[:, 0])
    seen.reached[wp.wp_all[ok_wp]] = True
    counts["waypoints_reached"] += int(ok_wp.sum())
    if not ok_wp.any():
        return []

    t = time.perf_counter()
    under = _sprayed(mesh, wp_T, ok_wp, need, fp, nozzle, rays)
    _add(times, "visibility", t)

    # sweeps: runs of consecutive reached waypoints of a line joined by short free motions
    t = time.perf_counter()
    cand = _candidate_sweeps(wp, ok_wp, wp_q, world)
    counts["candidate_sweeps"] += len(cand)
    cover = [np.asarray(under[ws].any(axis=0)) for _, ws in cand]  # (asarray: a no-op, typed for mypy)
    chosen = _multi_cover(mesh, cover, need, fp)
    _add(times, "selection", t)
    if not chosen:
        return []

    t = time.perf_counter()
    out = _tour(facets, lines, cand, cover, chosen, wp_q, wp_T, fp, q0, world, p)
    _add(times, "tour", t)
    return out


def _waypoints(
    facets: list[Facet], lines: list[_Line], need: NDArray[np.int64], fp: _FacePoints, nozzle: NozzleModel
) -> _Waypoints | None:
    """The waypoints of the lines over faces still needing passes whose spot can reach a point still
    short of passes (later stations get few); None when there are none."""
    from scipy.spatial import cKDTree

    fpts = fp.ids
    live = [i for i, ln in enumerate(lines) if need[fpts[ln.faces]].any()]
    if not live:
        return None
    offsets = np.cumsum([0] + [len(ln.points) for ln in lines])
    wp_all = np.concatenate([np.arange(offsets[i], offsets[i + 1]) for i in live])
    pts = np.concatenate([lines[i].points for i in live])
    seed_faces = np.concatenate([lines[i].faces for i in live])
    nrm = np.concatenate([np.repeat(facets[lines[i].facet].normal[None], len(lines[i].points), 0) for i in live])
    line_of = np.concatenate([np.full(len(lines[i].points), i) for i in live])
    extra = np.concatenate([np.full(len(lines[i].points), lines[i].extra) for i in live])
    pos = np.zeros((len(need), 3))
    pos[fpts.reshape(-1)] = fp.pos.reshape(-1, 3)
    d, _ = cKDTree(pos[need > 0]).query(pts, distance_upper_bound=nozzle.footprint_m)
    useful = np.isfinite(d)
    pts, seed_faces, nrm, line_of, wp_all, extra = (x[useful] for x in (pts, seed_faces, nrm, line_of, wp_all, extra))
    if len(pts) == 0:
        return None
    return _Waypoints(live, pts, seed_faces, nrm, line_of, wp_all, extra)


def _filtered(
    mesh: BinMesh,
    wp: _Waypoints,
    T_bin_base: NDArray[np.float64],
    nozzle: NozzleModel,
    world: Any,
    rays: Any,
    counts: Counter[str],
) -> Any:
    """The waypoints' nozzle poses through the planner's height, distance (of the flange), occlusion and
    camera-body filters and the lance's clearance."""
    from cellctl.geometry import robot_model as rm
    from cellctl.planning.filters import camera_collision_filter, distance_filter, height_filter, occlusion_filter
    from cellctl.planning.viewpoints import Viewpoints

    vp = _nozzle_poses(mesh, wp.pts, wp.nrm, wp.seed_faces, nozzle, ~wp.extra)
    keep = height_filter(vp, mesh, float(max(rm.CAMERA_BOX_SIZE)))
    # the distance filter on the flange, not the tip: the lance puts the tip out of the arm's reach otherwise
    flange = Viewpoints(vp.T @ invert(nozzle.T_flange_nozzle()), vp.seed, vp.rank, vp.seed_face, vp.seed_point)
    keep &= distance_filter(flange, T_bin_base[:3, 3], MAX_REACH_M)
    idx = np.flatnonzero(keep)
    counts["poses_generated"] += len(vp)
    counts["after_distance"] += len(idx)
    idx = idx[occlusion_filter(vp.subset(idx), mesh, rays)]
    counts["after_occlusion"] += len(idx)
    idx = idx[camera_collision_filter(vp.subset(idx), world)]
    idx = idx[_lance_free(vp.T[idx], nozzle, world)]
    counts["after_body_collision"] += len(idx)
    return vp.subset(idx)


def _reached(
    filtered: Any, tool: RobotModel, world: Any, T_bin_base: NDArray[np.float64], p: WashParams, counts: Counter[str]
) -> Any:
    """Reachability of the filtered poses, then connection to home; None when there is nothing to reach.

    IK solutions ranked and wrapped towards home, as the inspection planner's are: the arm drives between
    stations at home and the robot plans a move it cannot make straight through home (the tour still
    starts at q0)."""
    from cellctl.planning.reach import reachability

    q_home = np.asarray(tool.q_home, np.float64)

    def from_home(Q: NDArray[np.float64]) -> NDArray[np.bool_]:
        return world.motion_free(np.repeat(q_home[None], len(Q), axis=0), Q, _connect_step())

    reached = None
    if len(filtered):  # the arm shape: the most used one a straight motion from home reaches
        reached = reachability(filtered, tool, world, invert(T_bin_base), q_home, p.n_roll, joinable=from_home)
    if reached is not None and len(reached.index):
        reached = _connected(filtered, reached, tool, world, T_bin_base, p, counts)
    return reached


def _sprayed(
    mesh: BinMesh,
    wp_T: NDArray[np.float64],
    ok_wp: NDArray[np.bool_],
    need: NDArray[np.int64],
    fp: _FacePoints,
    nozzle: NozzleModel,
    rays: Any,
) -> NDArray[np.bool_]:
    """(waypoints, points) the face points under each reached waypoint's spot.

    The visibility stage with the nozzle's frustum, cut back to the cone and the footprint (any face:
    overspray is washed area too). A face counts as sprayed by a sweep when its centroid, its three
    corners and its inner points each lie under the spot of some waypoint of it: a face half under the
    jet keeps its powder at the other end."""
    from cellctl.planning.visibility import measurability

    fpts = fp.ids
    allf = np.arange(mesh.n_faces)
    wp_ids = np.flatnonzero(ok_wp)
    under = np.zeros((len(wp_T), len(need)), bool)
    C = measurability(wp_T[wp_ids], mesh, allf, nozzle.frustum_camera(), rays)
    for col, w in enumerate(wp_ids):
        rows = np.flatnonzero(C[:, col])
        if len(rows):
            real = fp.real[rows]  # (the padding repeats the centroid: checked once)
            nrm_r = np.broadcast_to(mesh.normals[rows, None], (*real.shape, 3))
            hit = nozzle.sprayed(wp_T[w], fp.pos[rows][real], nrm_r[real])
            under[w, fpts[rows][real][hit]] = True
    return under


def _candidate_sweeps(
    wp: _Waypoints, ok_wp: NDArray[np.bool_], wp_q: NDArray[np.float64], world: Any
) -> list[tuple[int, NDArray[np.int64]]]:
    """Per live raster line, its runs of consecutive reached waypoints joined by short free motions."""
    cand: list[tuple[int, NDArray[np.int64]]] = []
    for i in wp.live:
        run: list[int] = []
        for w in np.flatnonzero(wp.line_of == i):
            if (
                ok_wp[w]
                and run
                and (
                    np.abs(wp_q[w] - wp_q[run[-1]]).max() > MAX_SWEEP_STEP_RAD
                    or not world.motion_free(wp_q[run[-1]], wp_q[w])[0]
                )
            ):
                cand.append((i, np.array(run)))
                run = []
            if ok_wp[w]:
                run.append(int(w))
            elif run:
                cand.append((i, np.array(run)))
                run = []
        if run:
            cand.append((i, np.array(run)))
    return cand


def _multi_cover(
    mesh: BinMesh, cover: list[NDArray[np.bool_]], need: NDArray[np.int64], fp: _FacePoints
) -> Counter[int]:
    """Greedy multi-cover: each target face point gets the passes it still needs (a sweep may be
    chosen again: it is then run back and forth); per candidate sweep, how often it is chosen."""
    from scipy.sparse import csr_matrix

    fpts = fp.ids
    M = csr_matrix(np.array(cover, dtype=np.float64)) if cover else None
    left = need.copy()
    area = np.zeros(len(need))
    share = (mesh.areas / fp.real.sum(axis=1))[:, None] * fp.real  # each point stands for a share of its faces
    np.add.at(area, fpts.reshape(-1), share.reshape(-1))
    chosen: Counter[int] = Counter()
    while M is not None:
        gains = M @ (area * (left > 0))
        b = int(np.argmax(gains))
        if gains[b] <= 1e-12:
            break
        chosen[b] += 1
        left[cover[b]] = np.maximum(0, left[cover[b]] - 1)
    return chosen


def _tour(
    facets: list[Facet],
    lines: list[_Line],
    cand: list[tuple[int, NDArray[np.int64]]],
    cover: list[NDArray[np.bool_]],
    chosen: Counter[int],
    wp_q: NDArray[np.float64],
    wp_T: NDArray[np.float64],
    fp: _FacePoints,
    q0: NDArray[np.float64],
    world: Any,
    p: WashParams,
) -> list[tuple[Sweep, NDArray[np.int64], bool]]:
    """The chosen sweeps in tour order (node 0 = the start configuration), each with the points under it
    and whether the straight transit to it is free."""
    from cellctl.planning.tour import ant_colony, two_opt

    fpts = fp.ids
    sel = sorted(chosen)
    entry = np.vstack([q0] + [wp_q[cand[b][1][0]] for b in sel])
    exit_ = np.vstack([q0] + [wp_q[cand[b][1][-1 if chosen[b] % 2 else 0]] for b in sel])
    D = np.abs(exit_[:, None, :] - entry[None, :, :]).max(axis=2)
    D = np.minimum(D, D.T)
    np.fill_diagonal(D, 0.0)
    if len(sel) > 1:  # long tours: fewer ants and rounds (the 2-opt repairs what they leave)
        big = len(sel) > 40
        rng = np.random.default_rng(p.seed)
        order = two_opt(D, ant_colony(D, rng, n_ants=20 if big else None, iterations=40 if big else 150))
    else:
        order = np.arange(len(sel) + 1)
    out: list[tuple[Sweep, NDArray[np.int64], bool]] = []
    prev = q0
    for node in order[1:]:
        b = sel[int(node) - 1]
        ws = cand[b][1]
        fc = facets[lines[cand[b][0]].facet]
        faces = np.flatnonzero(cover[b][fpts].all(axis=1))
        sw = Sweep(fc.region, fc.surface, wp_T[ws].copy(), wp_q[ws].copy(), faces, int(chosen[b]))
        out.append((sw, np.flatnonzero(cover[b]), bool(world.motion_free(prev, wp_q[ws[0]])[0])))
        prev = exit_[int(node)]
    return out


def _connected(
    vp: Any,
    reached: Any,
    tool: RobotModel,
    world: Any,
    T_bin_base: NDArray[np.float64],
    p: WashParams,
    counts: Counter[str],
) -> Any:
    """The reached waypoints the arm can get to: each joined to the arm's home by straight
    collision-free joint motions (directly or through other waypoints), the inspection planner's
    connection (:func:`cellctl.planning.whole.connect`).

    Why home: a sweep the robot cannot move straight to from where it stands is planned through
    home (``_plan`` in the robot worker), in ``robot.plan_timeout_s``. Reachability's arm shape is
    the one most of a station's waypoints can use, so a few residue waypoints could get a flipped
    shoulder no planner connects (the demo's wash story: a sweep at shoulder +3.03 rad refused every
    round). A waypoint not joined takes its next-best solution that is, or is left unreached.
    """
    from cellctl.planning.whole.connection import connect

    q_home = np.asarray(tool.q_home, np.float64)
    con = connect(vp, reached, tool, world, invert(T_bin_base), q_home, p.n_roll, None, _connect_step())
    counts["waypoints_replaced_unconnected"] += con.replaced
    counts["waypoints_unconnected"] += con.unconnected
    return con.reached


def _connect_step() -> float:
    """The connection's motion check step (rad): the inspection planner's
    (:data:`cellctl.planning.whole.connection.COARSE_STEP_RAD`)."""
    from cellctl.planning.whole.connection import COARSE_STEP_RAD

    return float(COARSE_STEP_RAD)
