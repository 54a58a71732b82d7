"""The wash planner: :func:`plan_wash` as a sequence of stages over one :class:`_WashState`.

Targets and raster seeds (:func:`_targets`), the first cover pass station by station, most
still-needed waypoints within reach first (:func:`_first_pass`), the residue pass for the points it
left short (:func:`_residue_pass`), the plan with what stayed unwashable (:func:`_finish`).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.catalog import BinMesh
from cellctl.planning.robot import RobotModel
from cellctl.washing.nozzle import NozzleModel
from cellctl.washing.plan.budget import _Budget, _CpuRate
from cellctl.washing.plan.records import MAX_REACH_M, Sweep, Unwashable, WashParams, WashPlan, _empty
from cellctl.washing.plan.seeds import _face_points, _FacePoints, _Line, _raster, _residue_lines
from cellctl.washing.plan.station import _add, _Seen, _station
from cellctl.washing.targets import Facet, dilate, dirty_from_map, face_adjacency, facets_of

__all__ = ["plan_wash"]


@dataclass
class _WashState:
    """What the stages of one wash plan share: the request, the targets and seeds (:func:`_targets`),
    the demand left per face point, and the sweeps kept so far with the stations they came from."""

    mesh: BinMesh
    nozzle: NozzleModel
    robot: RobotModel
    p: WashParams
    poses: list[NDArray[np.float64]]
    q0: NDArray[np.float64]
    cpu0: float
    dirty: NDArray[np.bool_]
    source: str | None
    targets: NDArray[np.bool_]
    adj: list[NDArray[np.int64]]
    facets: list[Facet]
    lines: list[_Line]
    rays: Any
    fp: _FacePoints
    need: NDArray[np.int64]
    seen: _Seen
    rate: _CpuRate
    times: dict[str, float] = field(default_factory=dict)
    counts: Counter[str] = field(default_factory=Counter)
    sweeps: list[Sweep] = field(default_factory=list)
    transits: list[bool] = field(default_factory=list)
    used: list[int] = field(default_factory=list)
    tried: set[int] = field(default_factory=set)
    point_passes: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))


def plan_wash(
    mesh: BinMesh,
    dirt_map: dict[str, Any] | None,
    stations: Sequence[NDArray[np.float64]],
    nozzle: NozzleModel,
    robot: RobotModel,
    params: WashParams | None = None,
) -> WashPlan:
    """Plan the sweeps that wash the dirt map's dirty faces from the given base poses.

    The station with the most still-needed waypoints within the arm's reach goes first; each
    next one plans only what the earlier ones left short of its passes (at most
    ``params.max_stations`` are used; one that adds nothing is not).

    Args:
        mesh: the bin mesh (bin frame).
        dirt_map: the CycleResult's ``dirt_map`` (``face_p`` or ``seen_dirty``); None → a plan
            with no sweeps and the reason.
        stations: robot base poses ``T_bin_base`` (4, 4) the base may wash from (the measured
            one at wash time first).
        nozzle: the nozzle model.
        robot: the arm (its camera tool frame is replaced by the nozzle's).
        params: thresholds, rolls, clearance, seed.

    Raises:
        ClassifierError / PlanningError: a malformed dirt map, or no station.
    """
    from cellctl.errors import PlanningError

    p = params or WashParams()
    poses = [np.asarray(T, np.float64) for T in stations]
    if not poses:
        raise PlanningError("a wash plan needs at least one base pose (station); got none")
    q0 = np.asarray(p.q_start if p.q_start is not None else robot.q_home, np.float64)
    cpu0 = time.process_time()
    t = time.perf_counter()
    if dirt_map is None:
        return _empty(mesh, nozzle, poses, q0, "no dirt map: the wash needs a cycle's dirt map (inspect first)")
    dirty, source = dirty_from_map(dirt_map, mesh.n_faces, p.threshold)
    if not dirty.any():
        return _empty(mesh, nozzle, poses, q0, "the dirt map has no dirty face: nothing to wash", dirty, dirty, source)
    ws = _targets(mesh, nozzle, robot, p, poses, q0, cpu0, dirty, source, t)
    _first_pass(ws)
    if ws.need.any() and p.residue_rolls > 0:
        _residue_pass(ws)
    return _finish(ws)


def _targets(
    mesh: BinMesh,
    nozzle: NozzleModel,
    robot: RobotModel,
    p: WashParams,
    poses: list[NDArray[np.float64]],
    q0: NDArray[np.float64],
    cpu0: float,
    dirty: NDArray[np.bool_],
    source: str | None,
    t: float,
) -> _WashState:
    """The plan's state: the dirty faces dilated to targets, their facets and raster lines, the demand
    (``required_passes`` on every point of every target face), the collision world built once."""
    from cellctl.planning.raycast import RayCaster

    targets = dilate(mesh, dirty, p.margin_m)
    adj = face_adjacency(mesh)
    facets = facets_of(mesh, targets, adj)
    lines = [ln for k, fc in enumerate(facets) for ln in _raster(mesh, fc, k, nozzle.line_spacing_m)]
    times = {"targets": time.perf_counter() - t}
    rays = RayCaster(mesh.vertices, mesh.faces)
    # demand is counted on points, each face's centroid and corners (and more inside a face too
    # long for them): a face is washed when all of them have been under the jet, whichever sweeps
    # put them there; every part of a face within a spot's radius of a point, so spots at its points cover it
    fp = _face_points(mesh, nozzle.footprint_m / 2)
    need = np.zeros(int(fp.ids.max()) + 1, np.int64)
    need[fp.ids[targets].reshape(-1)] = nozzle.required_passes
    seen = _Seen(len(np.concatenate([ln.faces for ln in lines])))
    _warm(mesh, nozzle, robot, poses[0], p)
    # the rate is measured on warm stations: the first plan in a process imports the planning
    # stack and builds the bin's collision grid (about 2 s once), which no further station pays
    rate = _CpuRate(p.cpu_budget_s)
    return _WashState(
        mesh, nozzle, robot, p, poses, q0, cpu0, dirty, source, targets, adj, facets, lines, rays, fp, need, seen,
        rate, times, point_passes=np.zeros_like(need),
    )  # fmt: skip


def _take(ws: _WashState, st: list[tuple[Sweep, NDArray[np.int64], bool]], k: int) -> None:
    """Keep station ``k``'s sweeps and count their passes on the points under them."""
    for sw, pts_under, free in st:
        ws.sweeps.append(Sweep(sw.region, sw.surface, sw.T_bin_noz, sw.q, sw.faces, sw.passes, station=k))
        ws.transits.append(free)
        ws.need[pts_under] = np.maximum(0, ws.need[pts_under] - sw.passes)
        ws.point_passes[pts_under] += sw.passes


def _first_pass(ws: _WashState) -> None:
    """Station after station, the one with the most still-needed waypoints within the arm's reach
    first, until every point has its passes, ``max_stations`` are used or none is left to try."""
    p, poses, fpts = ws.p, ws.poses, ws.fp.ids
    wp_pts = np.concatenate([ln.points for ln in ws.lines])
    wp_faces = np.concatenate([ln.faces for ln in ws.lines])
    while ws.need.any() and len(ws.used) < p.max_stations and len(ws.tried) < len(poses):
        live = ws.need[fpts[wp_faces]].any(axis=1)
        near = [
            -1 if k in ws.tried else int((np.linalg.norm(wp_pts[live] - T[:3, 3], axis=1) <= MAX_REACH_M).sum())
            for k, T in enumerate(poses)
        ]
        k = int(np.argmax(near))
        if near[k] <= 0:
            break
        ws.tried.add(k)
        budget = _Budget(ws.rate, ws.cpu0, "stations_over_budget")
        st = _station(
            ws.mesh, ws.facets, ws.lines, poses[k], ws.need, ws.fp, ws.nozzle, ws.robot, p, ws.q0, ws.rays, ws.seen,
            ws.times, ws.counts, budget,
        )  # fmt: skip
        if not st:
            continue
        ws.used.append(k)
        _take(ws, st, k)


def _residue_pass(ws: _WashState) -> None:
    """Second cover pass on the residue.

    The first pass aims each raster waypoint along its facet's mean normal and fixes one arm shape per
    station for the bulk of them; a face it left short (at a facet's edge, on a curved wall, under a spot
    that misses a corner) gets its own short sweep aimed along its own normal, and reachability picks
    the shape and rolls that suit those few waypoints alone."""
    p, poses, nozzle, counts = ws.p, ws.poses, ws.nozzle, ws.counts
    t = time.perf_counter()
    rp = replace(p, n_roll=max(p.n_roll, p.residue_rolls))
    r_facets, r_lines = _residue_lines(ws.mesh, ws.facets, ws.fp, ws.need, ws.targets)
    r_seen = _Seen(sum(len(ln.points) for ln in r_lines))
    r_pts = np.concatenate([ln.points for ln in r_lines]) if r_lines else np.zeros((0, 3))
    # a point is within the nozzle's reach from a base when the flange is (the distance filter's
    # test): MAX_REACH_M plus the lance and the longest stand-off. On the points themselves it left
    # out the one station that reached the demo's dirty sliver from home (round 3, face 4365)
    lance = float(np.linalg.norm(nozzle.T_flange_nozzle()[:3, 3])) + max(nozzle.distances)
    near = [int((np.linalg.norm(r_pts - T[:3, 3], axis=1) <= MAX_REACH_M + lance).sum()) for T in poses]
    before = int((ws.need > 0).sum())
    # the same unit (a pose and roll through IK and collision checks) as the first pass: its rate holds
    ws.rate.first_free = False
    for k in sorted(range(len(poses)), key=lambda k: -near[k]):
        if not ws.need.any():
            break
        if near[k] <= 0 or (k not in ws.used and len(ws.used) >= p.max_stations):
            continue
        budget = _Budget(ws.rate, ws.cpu0, "residue_stations_over_budget")
        skipped = counts[budget.key]
        st = _station(
            ws.mesh, r_facets, r_lines, poses[k], ws.need, ws.fp, nozzle, ws.robot, rp, ws.q0, ws.rays, r_seen, {},
            counts, budget,
        )  # fmt: skip
        counts["residue_stations"] += counts[budget.key] == skipped
        if st and k not in ws.used:
            ws.used.append(k)
        _take(ws, st, k)
    counts["residue_points"] = before
    counts["residue_points_left"] = int((ws.need > 0).sum())
    _add(ws.times, "residue", t)


def _finish(ws: _WashState) -> WashPlan:
    """The plan: passes per face, covered and washed faces, the unwashable pieces with why, the reason
    when nothing is swept."""
    mesh, counts, times = ws.mesh, ws.counts, ws.times
    passes = ws.point_passes[ws.fp.ids].min(axis=1)
    covered = ws.targets & (passes > 0)
    seed_faces = np.concatenate([ln.faces for ln in ws.lines])
    unwashable = _unwashable(mesh, ws.targets & ~covered, ws.facets, seed_faces, ws.seen, ws.adj)
    counts["stations_tried"] = len(ws.tried)
    counts["stations_used"] = len(ws.used)
    counts["sweeps"] = len(ws.sweeps)
    times["total"] = sum(times.values())
    reason = None
    if not ws.sweeps:
        # each piece named (how big, where, which faces; the largest three): the cycle ends dirty with this reason
        big = sorted(unwashable, key=lambda u: -u.area_m2)
        named = [u.describe() + f": {u.reason}" for u in big[:3]] + [f"{len(big) - 3} more"] * (len(big) > 3)
        reason = "no nozzle pose reaches any dirty region: " + "; ".join(named)
    return WashPlan(
        sweeps=tuple(ws.sweeps),
        transits_free=tuple(ws.transits),
        dirty=ws.dirty,
        targets=ws.targets,
        covered=covered,
        washed=passes > 0,
        passes=passes,
        unwashable=unwashable,
        required_passes=ws.nozzle.required_passes,
        stations=tuple(ws.poses),
        q_start=ws.q0,
        reason=reason,
        source=ws.source,
        counts=dict(counts),
        times_s=times,
        cpu_s=time.process_time() - ws.cpu0,
    )


def _warm(
    mesh: BinMesh, nozzle: NozzleModel, robot: RobotModel, T_bin_base: NDArray[np.float64], p: WashParams
) -> None:
    """Import the planning stages and build the bin's collision world (cached per mesh) once."""
    from cellctl.planning import filters, reach, tour, visibility  # noqa: F401
    from cellctl.planning.collision import PlanningWorld

    PlanningWorld(mesh, nozzle.robot_with_nozzle(robot), T_bin_base, margin=p.margin)


def _unwashable(
    mesh: BinMesh,
    missed: NDArray[np.bool_],
    facets: list[Facet],
    seed_faces: NDArray[np.int64],
    seen: _Seen,
    adj: list[NDArray[np.int64]],
) -> tuple[Unwashable, ...]:
    """Missed target faces, grouped into connected pieces, each with the furthest stage it got to."""
    if not missed.any():
        return ()
    region_of = np.full(mesh.n_faces, -1)
    for fc in facets:
        region_of[fc.faces] = fc.region
    out = []
    for piece in facets_of(mesh, missed, adj):
        f = piece.faces
        near = np.isin(seed_faces, f)
        if not near.any():
            reason = "no raster waypoint lands on it (smaller than the raster step)"
        elif not seen.filtered[near].any():
            reason = "from every station, each nozzle pose for it is out of reach, occluded, or hits the bin"
        elif not seen.reached[near].any():
            reason = (
                "from every station, no collision-free arm configuration within the joint limits that a straight "
                "motion joins to the arm's home holds the nozzle there"
            )
        else:
            reason = "the reachable poses' jet meets it outside the working distance or incidence limit"
        a = mesh.areas[f]
        out.append(
            Unwashable(
                int(region_of[f[0]]),
                int(mesh.surface[f[0]]),
                f,
                float(a.sum()),
                (mesh.centroids[f] * a[:, None]).sum(0) / a.sum(),
                reason,
            )
        )
    return tuple(out)
