"""Wash planning: a dirt map → raster sweeps of the nozzle over the dirty regions, ordered.

The inspection planner's stages, called with the nozzle instead of the camera (paper §IV: "replacing
the inspection camera … with a washing nozzle and changing the camera pin-hole model with the
model defining the nozzle frustum of action"):

====================================  ===============================================================
step                                  what runs
====================================  ===============================================================
targets                               faces ≥ threshold (or ``seen_dirty``), dilated by the margin
                                      (:mod:`cellctl.washing.targets`), regions and facets
seeds                                 raster waypoints on each facet: lines ``footprint·(1−overlap)``
                                      apart, a waypoint every half line spacing
viewpoints + filters                  :func:`~cellctl.planning.viewpoints.generate_viewpoints` at the
                                      nozzle's stand-offs (jet along −normal), the planner's height,
                                      distance, occlusion and camera-body filters, plus the lance
reachability                          :func:`~cellctl.planning.reach.reachability` with the robot's
                                      tool frame at the nozzle (:meth:`NozzleModel.robot_with_nozzle`),
                                      then :func:`~cellctl.planning.whole.connect`: only arm
                                      configurations joined to home by straight free motions
visibility → sprayed                  :func:`~cellctl.planning.visibility.measurability` with the
                                      nozzle's frustum camera, cut to the cone and footprint
sweeps                                runs of consecutive reachable waypoints of one raster line
                                      joined by short collision-free joint motions
set cover                             greedy multi-cover over sweeps: every target face gets
                                      ``required_passes`` sweeps (a sweep may be chosen again:
                                      it is then run back and forth)
tour                                  :func:`~cellctl.planning.tour.ant_colony` + 2-opt over the
                                      sweeps from the start configuration; transit motions checked
====================================  ===============================================================

Target faces no sweep sprays are **unwashable**, grouped by region with the stage that lost them.
No dirt map → a plan with no passes and the reason (no motion). Frames: bin frame, nozzle
frame +Z along the jet. Metres, radians.
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
from cellctl.geometry.transforms import invert
from cellctl.planning.robot import RobotModel
from cellctl.surface import INTERNAL, SURFACES
from cellctl.washing.nozzle import NozzleModel
from cellctl.washing.targets import Facet, dilate, dirty_from_map, face_adjacency, facets_of

__all__ = ["Sweep", "Unwashable", "WashParams", "WashPlan", "plan_wash"]

MAX_SWEEP_STEP_RAD = 0.6  # joint jump between neighbouring waypoints that still counts as one sweep
MAX_REACH_M = 1.3
OPENING_RISE_M = 0.1  # internal jets radiate from this far above the opening's centre


@dataclass(frozen=True)
class WashParams:
    """How to turn a dirt map into a wash plan.

    Attributes:
        threshold: face probability that is washed.
        margin_m: dilation of the dirty faces.
        n_roll: rolls about the jet tried by reachability (the jet is round: any roll sprays alike).
        residue_rolls: rolls of the second cover pass, which replans every station for only the
            target points the first pass left short of their passes (0: no second pass).
        cpu_budget_s: the plan's CPU ceiling (keeps a round's planning within its 10 s when much
            dirt is out of reach; 2 s below it for what is not predicted): a station after the
            first (first or residue pass) runs its reachability only when the CPU used so far plus
            its predicted cost (its filtered poses times rolls, at the CPU per pose and roll
            measured on this plan's stations) fits; the stations skipped are counted in
            ``counts["stations_over_budget"]`` / ``["residue_stations_over_budget"]`` and their dirt
            is left for the next round.
        margin: collision clearance, m.
        max_stations: most base poses one wash plan uses.
        seed: seeds the tour's ant colony.
        q_start: start configuration (None: the robot's home).
    """

    threshold: float = 0.5
    margin_m: float = 0.02
    n_roll: int = 4
    residue_rolls: int = 12
    cpu_budget_s: float = 8.0
    max_stations: int = 8
    margin: float = 0.005
    seed: int = 0
    q_start: tuple[float, ...] | None = None


@dataclass(frozen=True)
class Sweep:
    """One continuous pass of the jet along a raster line.

    Attributes:
        region, surface: the target region it washes and its surface tag.
        T_bin_noz: (K, 4, 4) nozzle poses along the sweep, in the order they are run.
        q: (K, 6) joint configurations, rad.
        faces: target faces it sprays.
        passes: how many times it is run (back and forth).
        station: index of the base pose it is run from.
    """

    region: int
    surface: int
    T_bin_noz: NDArray[np.float64]
    q: NDArray[np.float64]
    faces: NDArray[np.int64]
    passes: int = 1
    station: int = 0

    @property
    def length_m(self) -> float:
        p = self.T_bin_noz[:, :3, 3]
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


@dataclass(frozen=True)
class Unwashable:
    """A piece of a target region no sweep sprays: its faces, area and why."""

    region: int
    surface: int
    faces: NDArray[np.int64]
    area_m2: float
    centroid: NDArray[np.float64]
    reason: str

    def describe(self) -> str:
        """The piece in words: its size, surface, centre (bin frame, mm) and first faces."""
        ids = ", ".join(str(int(f)) for f in self.faces[:5]) + (", …" if len(self.faces) > 5 else "")
        c = ", ".join(f"{v * 1e3:.0f}" for v in self.centroid)
        return f"{self.area_m2 * 1e4:.0f} cm² of the {SURFACES[self.surface]} surface at ({c}) mm, faces {ids}"


@dataclass
class WashPlan:
    """The ordered sweeps, what they cover and what they cannot.

    Attributes:
        sweeps: in execution order.
        transits_free: per sweep, whether the straight joint motion from the previous sweep's
            end (or the start) is collision-free; False ones go via the start configuration.
        dirty: (F,) the faces the dirt map calls dirty; targets: after dilation.
        covered: (F,) target faces some sweep sprays; washed: (F,) any face a sweep sprays.
        passes: (F,) sweeps spraying each face.
        unwashable: target pieces no sweep reaches.
        reason: set when there is nothing to do or nothing can be done (no motion then).
        source: where the dirty faces came from (``face_p``, ``seen_dirty``) or None.
        counts, times_s: what each step kept and spent (wall clock).
        cpu_s: the process CPU time the plan took (the wall clock counts other processes' load too).
    """

    sweeps: tuple[Sweep, ...]
    transits_free: tuple[bool, ...]
    dirty: NDArray[np.bool_]
    targets: NDArray[np.bool_]
    covered: NDArray[np.bool_]
    washed: NDArray[np.bool_]
    passes: NDArray[np.int64]
    unwashable: tuple[Unwashable, ...]
    required_passes: int
    stations: tuple[NDArray[np.float64], ...]
    q_start: NDArray[np.float64]
    reason: str | None = None
    source: str | None = None
    counts: dict[str, int] = field(default_factory=dict)
    times_s: dict[str, float] = field(default_factory=dict)
    cpu_s: float = 0.0

    @property
    def moves(self) -> bool:
        return bool(self.sweeps)

    def summary(self, mesh: BinMesh) -> dict[str, Any]:
        """JSON-ready totals (areas in m²)."""
        a = mesh.areas
        return {
            "reason": self.reason,
            "source": self.source,
            "sweeps": len(self.sweeps),
            "passes_run": int(sum(s.passes for s in self.sweeps)),
            "waypoints": int(sum(len(s.q) * s.passes for s in self.sweeps)),
            "sweep_length_m": round(sum(s.length_m * s.passes for s in self.sweeps), 3),
            "dirty_m2": round(float(a[self.dirty].sum()), 5),
            "target_m2": round(float(a[self.targets].sum()), 5),
            "covered_m2": round(float(a[self.covered].sum()), 5),
            "washed_m2": round(float(a[self.washed].sum()), 5),
            "full_passes_m2": round(float(a[self.targets & (self.passes >= self.required_passes)].sum()), 5),
            "unwashable": [
                {"region": u.region, "faces": len(u.faces), "area_m2": round(u.area_m2, 5), "reason": u.reason}
                for u in self.unwashable
            ],
            "transits_via_start": int(sum(not f for f in self.transits_free)),
            "stations_used": sorted({s.station for s in self.sweeps}),
            "counts": dict(self.counts),
            "times_s": {k: round(v, 3) for k, v in self.times_s.items()},
            "cpu_s": round(self.cpu_s, 3),
        }


def _empty(
    mesh: BinMesh,
    nozzle: NozzleModel,
    poses: list[NDArray[np.float64]],
    q0: NDArray[np.float64],
    reason: str,
    dirty: NDArray[np.bool_] | None = None,
    targets: NDArray[np.bool_] | None = None,
    source: str | None = None,
) -> WashPlan:
    z = np.zeros(mesh.n_faces, bool)
    return WashPlan(
        sweeps=(),
        transits_free=(),
        dirty=z if dirty is None else dirty,
        targets=z if targets is None else targets,
        covered=z.copy(),
        washed=z.copy(),
        passes=np.zeros(mesh.n_faces, np.int64),
        unwashable=(),
        required_passes=nozzle.required_passes,
        stations=tuple(poses),
        q_start=q0,
        reason=reason,
        source=source,
    )


# --- seeds: raster waypoints per facet -------------------------------------------------------


@dataclass(frozen=True)
class _Line:
    facet: int
    points: NDArray[np.float64]  # (K, 3) surface points along the line, in sweep order
    faces: NDArray[np.int64]  # (K,) nearest facet face of each
    extra: bool = False  # a residue candidate tilted off its point's normal: no internal-rule jet of its own


def _raster(mesh: BinMesh, fc: Facet, k: int, spacing: float) -> list[_Line]:
    """Boustrophedon raster lines over one facet, lines ``spacing`` apart along its longer extent."""
    from scipy.spatial import cKDTree

    n = fc.normal
    c = mesh.centroids[fc.faces]
    o = (c * mesh.areas[fc.faces, None]).sum(0) / mesh.areas[fc.faces].sum()
    # the raster spans the facet's triangles, corners included, not only their centroids
    corners = mesh.vertices[mesh.faces[fc.faces]]  # (n, 3, 3)
    ext = np.concatenate([c, corners.reshape(-1, 3)])
    ext_face = np.concatenate([fc.faces, np.repeat(fc.faces, 3)])
    helper = np.array([0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    uv = np.stack([(ext - o) @ e1, (ext - o) @ e2], axis=1)
    if len(fc.faces) > 2:  # sweep along the principal axis: fewer, longer lines
        w, V = np.linalg.eigh(np.cov(uv.T))
        a = V[:, int(np.argmax(w))]
        e1, e2 = a[0] * e1 + a[1] * e2, -a[1] * e1 + a[0] * e2
        uv = np.stack([(ext - o) @ e1, (ext - o) @ e2], axis=1)
    step = 0.7 * spacing  # a waypoint's spot (radius ≥ 0.71·spacing) then reaches half-way to the next line's
    tree = cKDTree(uv)
    lo, hi = uv.min(0), uv.max(0)
    reach = step  # a waypoint within a step of some point of the facet's triangles
    lines: list[_Line] = []
    n_rows = max(1, int(np.ceil((hi[1] - lo[1]) / spacing)))
    v0 = (lo[1] + hi[1]) / 2 - (n_rows - 1) * spacing / 2
    us = np.arange(lo[0], hi[0] + step * 0.5, step) if hi[0] > lo[0] else np.array([lo[0]])
    for r in range(n_rows):
        v = v0 + r * spacing
        q = np.stack([us, np.full(len(us), v)], axis=1)
        d, j = tree.query(q)
        ok = d <= reach
        if not ok.any():
            continue
        q, j = q[ok], j[ok]
        if r % 2:
            q, j = q[::-1], j[::-1]
        P = o + q[:, :1] * e1 + q[:, 1:] * e2
        P += ((ext[j] - P) @ n)[:, None] * n  # onto the plane of the nearest triangle point
        lines.append(_Line(k, P, ext_face[j]))
    return lines


# --- the planner -------------------------------------------------------------------------


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
    times: dict[str, float] = {}
    cpu0 = time.process_time()
    t = time.perf_counter()
    if dirt_map is None:
        return _empty(mesh, nozzle, poses, q0, "no dirt map: the wash needs a cycle's dirt map (inspect first)")
    dirty, source = dirty_from_map(dirt_map, mesh.n_faces, p.threshold)
    if not dirty.any():
        return _empty(mesh, nozzle, poses, q0, "the dirt map has no dirty face: nothing to wash", dirty, dirty, source)
    targets = dilate(mesh, dirty, p.margin_m)
    adj = face_adjacency(mesh)
    facets = facets_of(mesh, targets, adj)
    lines = [ln for k, fc in enumerate(facets) for ln in _raster(mesh, fc, k, nozzle.line_spacing_m)]
    times["targets"] = time.perf_counter() - t
    from cellctl.planning.raycast import RayCaster

    rays = RayCaster(mesh.vertices, mesh.faces)
    # demand is counted on points, each face's centroid and corners (and more inside a face too
    # long for them): a face is washed when all of them have been under the jet, whichever sweeps
    # put them there; every part of a face within a spot's radius of a point, so spots at its points cover it
    fp = _face_points(mesh, nozzle.footprint_m / 2)
    fpts = fp.ids
    need = np.zeros(int(fpts.max()) + 1, np.int64)
    need[fpts[targets].reshape(-1)] = nozzle.required_passes
    sweeps: list[Sweep] = []
    transits: list[bool] = []
    counts: Counter[str] = Counter()
    used: list[int] = []
    point_passes = np.zeros_like(need)
    seen = _Seen(len(np.concatenate([ln.faces for ln in lines])))
    # the stations with the most still-needed waypoints within the arm's reach go first
    wp_pts = np.concatenate([ln.points for ln in lines])
    wp_faces = np.concatenate([ln.faces for ln in lines])
    tried: set[int] = set()
    _warm(mesh, nozzle, robot, poses[0], p)
    # the rate is measured on warm stations: the first plan in a process imports the planning
    # stack and builds the bin's collision grid (about 2 s once), which no further station pays
    rate = _CpuRate(p.cpu_budget_s)

    def take(st: list[tuple[Sweep, NDArray[np.int64], bool]], k: int) -> None:
        """Keep station ``k``'s sweeps and count their passes on the points under them."""
        for sw, pts_under, free in st:
            sweeps.append(Sweep(sw.region, sw.surface, sw.T_bin_noz, sw.q, sw.faces, sw.passes, station=k))
            transits.append(free)
            need[pts_under] = np.maximum(0, need[pts_under] - sw.passes)
            point_passes[pts_under] += sw.passes

    while need.any() and len(used) < p.max_stations and len(tried) < len(poses):
        live = need[fpts[wp_faces]].any(axis=1)
        near = [
            -1 if k in tried else int((np.linalg.norm(wp_pts[live] - T[:3, 3], axis=1) <= MAX_REACH_M).sum())
            for k, T in enumerate(poses)
        ]
        k = int(np.argmax(near))
        if near[k] <= 0:
            break
        tried.add(k)
        T_bin_base = poses[k]
        budget = _Budget(rate, cpu0, "stations_over_budget")
        st = _station(
            mesh, facets, lines, T_bin_base, need, fp, nozzle, robot, p, q0, rays, seen, times, counts, budget
        )
        if not st:
            continue
        used.append(k)
        take(st, k)
    if need.any() and p.residue_rolls > 0:
        # second cover pass on the residue: the first pass aims each raster waypoint along its
        # facet's mean normal and fixes one arm shape per station for the bulk of them; a face
        # it left short (at a facet's edge, on a curved wall, under a spot that misses a
        # corner) gets its own short sweep aimed along its own normal, and reachability picks
        # the shape and rolls that suit those few waypoints alone
        t = time.perf_counter()
        rp = replace(p, n_roll=max(p.n_roll, p.residue_rolls))
        r_facets, r_lines = _residue_lines(mesh, facets, fp, need, targets)
        r_seen = _Seen(sum(len(ln.points) for ln in r_lines))
        r_pts = np.concatenate([ln.points for ln in r_lines]) if r_lines else np.zeros((0, 3))
        # a point is within the nozzle's reach from a base when the flange is (the distance filter's
        # test): MAX_REACH_M plus the lance and the longest stand-off. On the points themselves it left
        # out the one station that reached the demo's dirty sliver from home (round 3, face 4365)
        lance = float(np.linalg.norm(nozzle.T_flange_nozzle()[:3, 3])) + max(nozzle.distances)
        near = [int((np.linalg.norm(r_pts - T[:3, 3], axis=1) <= MAX_REACH_M + lance).sum()) for T in poses]
        before = int((need > 0).sum())
        # the same unit (a pose and roll through IK and collision checks) as the first pass: its rate holds
        rate.first_free = False
        for k in sorted(range(len(poses)), key=lambda k: -near[k]):
            if not need.any():
                break
            if near[k] <= 0 or (k not in used and len(used) >= p.max_stations):
                continue
            budget = _Budget(rate, cpu0, "residue_stations_over_budget")
            skipped = counts[budget.key]
            st = _station(
                mesh, r_facets, r_lines, poses[k], need, fp, nozzle, robot, rp, q0, rays, r_seen, {}, counts, budget
            )
            counts["residue_stations"] += counts[budget.key] == skipped
            if st and k not in used:
                used.append(k)
            take(st, k)
        counts["residue_points"] = before
        counts["residue_points_left"] = int((need > 0).sum())
        _add(times, "residue", t)
    passes = point_passes[fpts].min(axis=1)
    covered = targets & (passes > 0)
    seed_faces = np.concatenate([ln.faces for ln in lines])
    unwashable = _unwashable(mesh, targets & ~covered, facets, seed_faces, seen, adj)
    counts["stations_tried"] = len(tried)
    counts["stations_used"] = len(used)
    counts["sweeps"] = len(sweeps)
    times["total"] = sum(times.values())
    reason = None
    if not sweeps:
        # each piece named (how big, where, which faces; the largest three): the cycle ends dirty with this reason
        big = sorted(unwashable, key=lambda u: -u.area_m2)
        named = [u.describe() + f": {u.reason}" for u in big[:3]] + [f"{len(big) - 3} more"] * (len(big) > 3)
        reason = "no nozzle pose reaches any dirty region: " + "; ".join(named)
    return WashPlan(
        sweeps=tuple(sweeps),
        transits_free=tuple(transits),
        dirty=dirty,
        targets=targets,
        covered=covered,
        washed=passes > 0,
        passes=passes,
        unwashable=unwashable,
        required_passes=nozzle.required_passes,
        stations=tuple(poses),
        q_start=q0,
        reason=reason,
        source=source,
        counts=dict(counts),
        times_s=times,
        cpu_s=time.process_time() - cpu0,
    )


def _warm(
    mesh: BinMesh, nozzle: NozzleModel, robot: RobotModel, T_bin_base: NDArray[np.float64], p: WashParams
) -> None:
    """Import the planning stages and build the bin's collision world (cached per mesh) once."""
    from cellctl.planning import filters, reach, tour, visibility  # noqa: F401
    from cellctl.planning.collision import PlanningWorld

    PlanningWorld(mesh, nozzle.robot_with_nozzle(robot), T_bin_base, margin=p.margin)


class _CpuRate:
    """CPU seconds per pose and roll through reachability (IK, collision checks: 80-95 % of a wash
    plan's CPU), measured on the stations planned so far: predicts whether one more station's
    reachability fits the plan's budget (``WashParams.cpu_budget_s``).

    Counted where the cost is: a station's filtered poses times the rolls tried, known just before
    its reachability runs. A station's waypoints in reach (the previous unit) mispredicted the
    residue pass by 5x (52 residue points, 5.7 s: 1177 poses x 12 rolls) and a mixed bin's round
    reached 10.4 s. The rest of a station (filters, cover, tour) is not predicted: the budget's
    margin below the 10 s target holds it.
    """

    def __init__(self, budget_s: float, prior: float = 0.0, first_free: bool = True) -> None:
        self.budget_s, self.prior, self.first_free = budget_s, prior, first_free
        self.cpu_s, self.units = 0.0, 0

    def per_unit(self) -> float:
        return self.cpu_s / self.units if self.units else self.prior

    def add(self, units: int, cpu_s: float) -> None:
        self.cpu_s += cpu_s
        self.units += units

    def predict(self, units: int) -> float:
        return units * self.per_unit()

    def fits(self, units: int, spent_s: float) -> bool:
        """Whether ``units`` more fit after ``spent_s`` (before anything is measured: the plan's first station)."""
        if self.first_free and not self.units:
            return True
        return spent_s + self.predict(units) <= self.budget_s


@dataclass
class _Budget:
    """A plan's CPU ceiling as one station sees it: the shared rate, the plan's CPU clock start, and
    the ``counts`` key a station skipped for it goes under."""

    rate: _CpuRate
    cpu0: float
    key: str


class _Seen:
    """Per raster waypoint, the furthest stage any station got it to (for the unwashable reasons)."""

    def __init__(self, n: int) -> None:
        self.filtered = np.zeros(n, bool)
        self.reached = np.zeros(n, bool)


def _add(times: dict[str, float], key: str, t0: float) -> None:
    times[key] = times.get(key, 0.0) + time.perf_counter() - t0


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
    from cellctl.geometry import robot_model as rm
    from cellctl.planning.collision import PlanningWorld
    from cellctl.planning.filters import camera_collision_filter, distance_filter, height_filter, occlusion_filter
    from cellctl.planning.reach import reachability
    from cellctl.planning.tour import ant_colony, two_opt
    from cellctl.planning.viewpoints import Viewpoints
    from cellctl.planning.visibility import measurability

    # seeds → nozzle poses → the planner's filters; only lines over faces still needing passes
    t = time.perf_counter()
    fpts = fp.ids
    live = [i for i, ln in enumerate(lines) if need[fpts[ln.faces]].any()]
    if not live:
        return []
    offsets = np.cumsum([0] + [len(ln.points) for ln in lines])
    wp_all = np.concatenate([np.arange(offsets[i], offsets[i + 1]) for i in live])
    pts = np.concatenate([lines[i].points for i in live])
    seed_faces = np.concatenate([lines[i].faces for i in live])
    nrm = np.concatenate([np.repeat(facets[lines[i].facet].normal[None], len(lines[i].points), 0) for i in live])
    line_of = np.concatenate([np.full(len(lines[i].points), i) for i in live])
    extra = np.concatenate([np.full(len(lines[i].points), lines[i].extra) for i in live])
    # only waypoints whose spot can reach a point still short of passes (later stations get few)
    from scipy.spatial import cKDTree

    pos = np.zeros((len(need), 3))
    pos[fpts.reshape(-1)] = fp.pos.reshape(-1, 3)
    d, _ = cKDTree(pos[need > 0]).query(pts, distance_upper_bound=nozzle.footprint_m)
    useful = np.isfinite(d)
    pts, seed_faces, nrm, line_of, wp_all, extra = (x[useful] for x in (pts, seed_faces, nrm, line_of, wp_all, extra))
    if len(pts) == 0:
        return []
    tool = nozzle.robot_with_nozzle(robot)
    world = PlanningWorld(mesh, tool, T_bin_base, margin=p.margin)
    vp = _nozzle_poses(mesh, pts, nrm, seed_faces, nozzle, ~extra)
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
    filtered = vp.subset(idx)
    seen.filtered[wp_all[filtered.seed]] = True
    _add(times, "generate_filter", t)

    t = time.perf_counter()
    units = len(filtered) * p.n_roll  # what reachability costs: IK and collision checks per pose and roll
    if budget is not None and not budget.rate.fits(units, time.process_time() - budget.cpu0):
        counts[budget.key] += 1
        return []
    c = time.process_time()
    # IK solutions ranked and wrapped towards home, as the inspection planner's are: the arm drives between
    # stations at home and the robot plans a move it cannot make straight through home (the tour still
    # starts at q0)
    q_home = np.asarray(tool.q_home, np.float64)

    def from_home(Q: NDArray[np.float64]) -> NDArray[np.bool_]:
        return world.motion_free(np.repeat(q_home[None], len(Q), axis=0), Q, _connect_step())

    reached = None
    if len(filtered):  # the arm shape: the most used one a straight motion from home reaches
        reached = reachability(filtered, tool, world, invert(T_bin_base), q_home, p.n_roll, joinable=from_home)
    if reached is not None and len(reached.index):
        reached = _connected(filtered, reached, tool, world, T_bin_base, p, counts)
    if budget is not None:
        budget.rate.add(units, time.process_time() - c)
    _add(times, "reachability", t)
    wp_q = np.full((len(pts), 6), np.nan)
    wp_T = np.full((len(pts), 4, 4), np.nan)
    if reached is not None and len(reached.index):
        s_idx = filtered.seed[reached.index]
        wp_q[s_idx], wp_T[s_idx] = reached.q, reached.T
    ok_wp = np.isfinite(wp_q[:, 0])
    seen.reached[wp_all[ok_wp]] = True
    counts["waypoints_reached"] += int(ok_wp.sum())
    if not ok_wp.any():
        return []

    # the faces each reached waypoint sprays: the visibility stage with the nozzle's frustum,
    # cut back to the cone and the footprint (any face: overspray is washed area too). A face
    # counts as sprayed by a sweep when its centroid, its three corners and its inner points each
    # lie under the spot of some waypoint of it: a face half under the jet keeps its powder at the
    # other end.
    t = time.perf_counter()
    allf = np.arange(mesh.n_faces)
    wp_ids = np.flatnonzero(ok_wp)
    under = np.zeros((len(pts), len(need)), bool)
    C = measurability(wp_T[wp_ids], mesh, allf, nozzle.frustum_camera(), rays)
    for col, w in enumerate(wp_ids):
        rows = np.flatnonzero(C[:, col])
        if len(rows):
            real = fp.real[rows]  # (the padding repeats the centroid: checked once)
            nrm_r = np.broadcast_to(mesh.normals[rows, None], (*real.shape, 3))
            hit = nozzle.sprayed(wp_T[w], fp.pos[rows][real], nrm_r[real])
            under[w, fpts[rows][real][hit]] = True
    _add(times, "visibility", t)

    # sweeps: runs of consecutive reached waypoints of a line joined by short free motions
    t = time.perf_counter()
    cand: list[tuple[int, NDArray[np.int64]]] = []
    for i in live:
        run: list[int] = []
        for w in np.flatnonzero(line_of == i):
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
    counts["candidate_sweeps"] += len(cand)
    cover = [under[ws].any(axis=0) for _, ws in cand]
    from scipy.sparse import csr_matrix

    M = csr_matrix(np.array(cover, dtype=np.float64)) if cover else None

    # greedy multi-cover: each target face gets the passes it still needs
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
    _add(times, "selection", t)
    if not chosen:
        return []

    # tour over the chosen sweeps (node 0 = the start configuration), then transit checks
    t = time.perf_counter()
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
    _add(times, "tour", t)
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
    from cellctl.planning.whole import connect

    q_home = np.asarray(tool.q_home, np.float64)
    con = connect(vp, reached, tool, world, invert(T_bin_base), q_home, p.n_roll, None, _connect_step())
    counts["waypoints_replaced_unconnected"] += con.replaced
    counts["waypoints_unconnected"] += con.unconnected
    return con.reached


def _connect_step() -> float:
    """The connection's motion check step (rad), from the module that defines :func:`connect`
    (planning.whole is being split into modules: issue 33)."""
    import importlib

    from cellctl.planning.whole import connect

    return float(importlib.import_module(connect.__module__).COARSE_STEP_RAD)


RESIDUE_TILTS_DEG = (0.0, 30.0, 50.0)
"""Jet tilts off a residue point's normal the second cover pass tries (50°: inside the default 60° incidence limit)."""
RESIDUE_AZIMUTHS = 6


def _residue_lines(
    mesh: BinMesh, facets: list[Facet], fp: _FacePoints, need: NDArray[np.int64], targets: NDArray[np.bool_]
) -> tuple[list[Facet], list[_Line]]:
    """Extra candidates for the target points still short of passes: one single-waypoint line
    per point and jet direction, aimed at the point (a corner pulled a fifth of the way into a target
    face it belongs to, off the edge) along the mean normal of its target faces and that normal
    tilted by :data:`RESIDUE_TILTS_DEG` at :data:`RESIDUE_AZIMUTHS` azimuths: the first pass's
    jet follows a facet's mean normal, which a corner on a crease or a face deep inside a
    narrow opening needs at another angle."""
    region_of = np.full(mesh.n_faces, -1)
    for fc in facets:
        region_of[fc.faces] = fc.region
    out_f: list[Facet] = []
    out_l: list[_Line] = []
    fpts, pos = fp.ids, fp.pos
    tf = np.flatnonzero(targets)
    short = need[fpts[tf]] > 0  # (T, K)
    done: set[int] = set()
    for row, col in zip(*np.nonzero(short), strict=True):
        pid = int(fpts[tf[row], col])
        if pid in done:
            continue
        done.add(pid)
        owners = tf[(fpts[tf] == pid).any(axis=1)]
        f = int(owners[0])
        nm = (mesh.normals[owners] * mesh.areas[owners, None]).sum(axis=0)
        nm = nm / max(float(np.linalg.norm(nm)), 1e-12)
        pt = 0.8 * pos[f, col] + 0.2 * mesh.centroids[f] if 1 <= col <= 3 else pos[f, col]  # corners only
        helper = np.array([0.0, 0.0, 1.0]) if abs(nm[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        e1 = np.cross(nm, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(nm, e1)
        dirs = [nm]
        for tilt in RESIDUE_TILTS_DEG[1:]:
            t = np.deg2rad(tilt)
            for k in range(RESIDUE_AZIMUTHS):
                az = 2 * np.pi * k / RESIDUE_AZIMUTHS
                dirs.append(np.cos(t) * nm + np.sin(t) * (np.cos(az) * e1 + np.sin(az) * e2))
        for j, d in enumerate(dirs):
            out_l.append(_Line(len(out_f), pt[None], np.array([f], np.int64), extra=j > 0))
            out_f.append(Facet(int(region_of[f]), int(mesh.surface[f]), np.array([f], np.int64), d))
    return out_f, out_l


@dataclass(frozen=True)
class _FacePoints:
    """The points demand is counted on, per face (F, K): ids (a point shared by faces has one id),
    positions, and which slots are real (the rest repeat the face's centroid, to keep K per face)."""

    ids: NDArray[np.int64]
    pos: NDArray[np.float64]
    real: NDArray[np.bool_]


def _face_points(mesh: BinMesh, spacing: float) -> _FacePoints:
    """Each face's centroid (id = face id), its corners (welded by position), and inside a face some
    part of which lies further than ``spacing`` from all of those, more points (farthest first, until
    every part of it is within ``spacing`` of one; ids after the corners'). The plan passes the raster's
    line spacing: a face is then represented as densely as a sweep covers it.

    Why: the demo's dirty sliver (face 4365 of the case study, 58 cm long and 5 cm wide, where the
    jet along its normal cannot go) had its powder between its centroid and a corner, 6 cm from both:
    the residue pass aimed at those four points only, and the powder between stayed."""
    key = np.round(mesh.vertices / 1e-5).astype(np.int64)
    _, weld = np.unique(key, axis=0, return_inverse=True)
    ids = np.concatenate([np.arange(mesh.n_faces)[:, None], mesh.n_faces + weld.reshape(-1)[mesh.faces]], axis=1)
    tri = mesh.vertices[mesh.faces]
    pos = np.concatenate([mesh.centroids[:, None], tri], axis=1)
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    extra: dict[int, NDArray[np.float64]] = {}
    for f in np.flatnonzero(longest > 1.5 * spacing):  # (a shorter face is within spacing of its corners)
        m = int(np.ceil(2 * longest[f] / spacing))  # a barycentric grid half the spacing apart
        i, j = np.meshgrid(np.arange(m + 1), np.arange(m + 1), indexing="ij")
        ok = i + j <= m
        b = np.stack([i[ok], j[ok], m - i[ok] - j[ok]], axis=1) / m
        cand = b @ tri[f]
        d = np.linalg.norm(cand[:, None] - pos[f][None], axis=2).min(axis=1)
        kept = []
        while d.max() > spacing:
            k = int(np.argmax(d))
            kept.append(cand[k])
            d = np.minimum(d, np.linalg.norm(cand - cand[k], axis=1))
        if kept:
            extra[int(f)] = np.array(kept)
    n_extra = max((len(v) for v in extra.values()), default=0)
    real = np.zeros((mesh.n_faces, 4 + n_extra), bool)
    real[:, :4] = True
    ids = np.concatenate([ids, np.repeat(ids[:, :1], n_extra, axis=1)], axis=1)
    pos = np.concatenate([pos, np.repeat(pos[:, :1], n_extra, axis=1)], axis=1)
    nxt = int(ids.max()) + 1
    for face, P in extra.items():  # not ``f``: above it is a numpy index, here a dict key (mypy)
        ids[face, 4 : 4 + len(P)] = np.arange(nxt, nxt + len(P))
        pos[face, 4 : 4 + len(P)] = P
        real[face, 4 : 4 + len(P)] = True
        nxt += len(P)
    return _FacePoints(ids, pos, real)


def _nozzle_poses(
    mesh: BinMesh,
    pts: NDArray[np.float64],
    nrm: NDArray[np.float64],
    faces: NDArray[np.int64],
    nozzle: NozzleModel,
    opening_rule: NDArray[np.bool_] | None = None,
) -> Any:
    """Candidate nozzle poses per waypoint, in preference order: the jet along −normal at each
    stand-off (the external viewpoint rule), then — inside the bin — the jet from the top
    opening's centre through the waypoint (the internal viewpoint rule) where that meets the
    face within the incidence limit."""
    from cellctl.planning.viewpoints import Viewpoints, generate_viewpoints

    d = nozzle.distances
    a = generate_viewpoints(pts, nrm, faces, "external", d)
    inside_ok = mesh.surface[faces] == INTERNAL
    if opening_rule is not None:
        inside_ok &= opening_rule
    inside = np.flatnonzero(inside_ok)
    if len(inside) == 0:
        return a
    top = (0.0, 0.0, float(mesh.vertices[:, 2].max()) + OPENING_RISE_M)
    b = generate_viewpoints(pts[inside], nrm[inside], faces[inside], "internal", d, origin=top)
    k = b.T[:, :3, 2]
    cos_inc = -np.einsum("ij,ij->i", k, nrm[inside][b.seed])
    ok = cos_inc >= np.cos(np.deg2rad(nozzle.max_incidence_deg)) - 1e-9
    ok &= cos_inc < 0.999  # where the two rules give the same jet, the first is enough
    b = b.subset(np.flatnonzero(ok))
    return Viewpoints(
        np.concatenate([a.T, b.T]),
        np.concatenate([a.seed, inside[b.seed]]),
        np.concatenate([a.rank, b.rank + len(d)]),
        np.concatenate([a.seed_face, b.seed_face]),
        np.concatenate([a.seed_point, b.seed_point]),
    )


def _lance_free(T_bin_noz: NDArray[np.float64], nozzle: NozzleModel, world: Any) -> NDArray[np.bool_]:
    """(N,) True where the lance (flange → tip) clears the bin and the floor."""
    if len(T_bin_noz) == 0:
        return np.zeros(0, bool)
    a, b = nozzle.lance_segment(T_bin_noz)
    f = np.linspace(0.0, 1.0, 5)
    P = (a[:, None] + (b - a)[:, None] * f[None, :, None]).reshape(-1, 3)
    thr = nozzle.lance_radius_m + world.margin
    grid = world.sim.grid
    hit = grid.interp(P) < thr
    if hit.any():
        idx = np.flatnonzero(hit)
        hit[idx] = grid.exact(P[idx]) < thr
    hit |= P[:, 2] - thr < world.floor_z
    return ~hit.reshape(len(T_bin_noz), -1).any(axis=1)


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
