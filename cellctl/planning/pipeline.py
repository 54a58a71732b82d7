"""The offline planning pipeline: mesh + base pose → ordered, reachable viewpoints (a :class:`Plan`).

:func:`make_plan` runs one function per stage (paper §IV-A), each with typed inputs and
outputs; the ``times_s`` key each stage is booked under:

=======================================  =================  ==========================
stage function                           ``times_s`` key    output
=======================================  =================  ==========================
:func:`generate_and_filter` (seeds,      generate_filter    :class:`Filtered`
viewpoints, 4 filters)
:func:`reach` (IK + collision, RRT*      reachability       :class:`Reachability`
in paper mode)
:func:`measure` (visible faces, C)       visibility         :class:`Visibility`
:func:`select` (Greedy Area + SA)        selection          :class:`Selection`
:func:`paper_tour` / :func:`fast_tour`   distance_matrix,   :class:`Tour`
(path costs, ant colony + 2-opt)         ordering
:func:`exact_cover` (HiGHS bound)        selection          :class:`Cover`
:func:`assemble`                         (total)            :class:`Plan`
=======================================  =================  ==========================

In fast mode :func:`select_and_order` repeats selection and tour while some selected
viewpoint turns out to be connected to no other by any motion (it is dropped, the rest
re-selected).
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry import robot_model as rm
from cellctl.geometry.catalog import BinMesh
from cellctl.geometry.transforms import invert, rotation_about, transform_from
from cellctl.planning.collision import PlanningWorld
from cellctl.planning.plan import (
    AreaStats,
    BasePose,
    CandidateCounts,
    Plan,
    PlannedViewpoint,
    PlanParams,
    ReachableViewpoint,
    SAStats,
    StageCounts,
    StageTimes,
)
from cellctl.planning.plan import frozen_array as _ro
from cellctl.planning.raycast import RayCaster
from cellctl.planning.reach import Reached
from cellctl.planning.robot import RobotModel
from cellctl.planning.select import SAResult
from cellctl.planning.viewpoints import Viewpoints

__all__ = [
    "PlanParams",
    "ProgressFn",
    "base_pose_from_xyz_yaw",
    "make_plan",
]

ProgressFn = Callable[[str, float, str], None]
"""``progress(stage, fraction 0..1, message)``."""

MAX_TOUR_ROUNDS = 12  # fast mode: plan-the-tour's-edges / re-order rounds
MAX_SELECT_ROUNDS = 4  # fast mode: re-select after dropping viewpoints no motion connects

STAGES = ("generate_filter", "reachability", "visibility", "selection", "distance_matrix", "ordering")


def base_pose_from_xyz_yaw(x: float, y: float, z: float, yaw_deg: float) -> NDArray[np.float64]:
    """``T_bin_base`` from the robot base position (m) and yaw (deg) in the bin frame (Z up)."""
    return transform_from(rotation_about((0, 0, 1), np.deg2rad(yaw_deg)), (x, y, z))


class _Stages:
    """Per-stage timing + progress fan-out (tqdm bar and/or a callback)."""

    def __init__(self, progress: ProgressFn | None, show_bars: bool) -> None:
        self.times = {k: 0.0 for k in STAGES}
        self.progress = progress
        self.show_bars = show_bars
        self._bar: Any = None
        self._stage = ""
        self._t0 = 0.0

    def start(self, stage: str, label: str) -> None:
        self._stage = stage
        self._t0 = time.perf_counter()
        if self.show_bars:
            import sys

            from tqdm import tqdm

            self._bar = tqdm(
                total=100, desc=f"{label:<16}", file=sys.stderr, leave=False, bar_format="{l_bar}{bar}| {elapsed}"
            )
        self.update(0, 1)

    def update(self, done: int, total: int, message: str = "") -> None:
        frac = 0.0 if total <= 0 else min(1.0, done / total)
        if self._bar is not None and int(100 * frac) != self._bar.n:
            self._bar.n = int(100 * frac)
            self._bar.refresh()
        if self.progress:
            self.progress(self._stage, frac, message)

    def end(self) -> None:
        self.update(1, 1)
        self.times[self._stage] += time.perf_counter() - self._t0
        if self._bar is not None:
            self._bar.close()
            self._bar = None


# --- what the stages share and hand on ---------------------------------------------------


@dataclass(frozen=True)
class Setup:
    """The inputs every stage reads: mesh, robot, parameters, base pose and the worlds built from them."""

    mesh: BinMesh
    robot: RobotModel
    params: PlanParams
    T_bin_base: NDArray[np.float64]
    T_base_bin: NDArray[np.float64]
    q_start: NDArray[np.float64]
    surf_faces: NDArray[np.int64]
    world: PlanningWorld
    rays: RayCaster
    rng: np.random.Generator


@dataclass(frozen=True)
class Filtered:
    """Seeds → viewpoints → height, distance, occlusion, camera-collision filters."""

    vp: Viewpoints
    generated: int
    seeds: int
    after_height: int
    after_distance: int
    after_occlusion: int
    after_camera_collision: int


@dataclass(frozen=True)
class Reachability:
    """The reachable viewpoints and what the (paper-mode) planner did for them."""

    reached: Reached
    planner_queries: int
    rrtconnect_fallbacks: int


@dataclass(frozen=True)
class Visibility:
    """Measurability matrix C (surface faces × reachable viewpoints) and the surface's face areas."""

    C: NDArray[np.bool_]
    face_areas: NDArray[np.float64]
    visible_all_m2: float


@dataclass(frozen=True)
class Selection:
    """Greedy Area set and the SA-reduced selection (columns of C)."""

    greedy: NDArray[np.int64]
    selected: NDArray[np.int64]
    sa: SAResult


@dataclass(frozen=True)
class Tour:
    """The visiting order over ``[start, *selected]`` and the path of each tour edge.

    Attributes:
        order: node order, node 0 = the start configuration, node k = ``selected[k - 1]``.
        D: (n, n) path costs between the nodes.
        approaches: per visited viewpoint (tour order), the planned path from the previous
            node, or None when the straight motion is used.
        counts: the stage counts of the path-cost matrix and the tour (``matrix_*``, ``tour_*``).
        isolated: selected nodes no motion connects (fast mode; dropped and re-selected).
    """

    order: NDArray[np.int64]
    D: NDArray[np.float64]
    approaches: tuple[NDArray[np.float64] | None, ...]
    counts: dict[str, int]
    isolated: tuple[int, ...] = ()


@dataclass(frozen=True)
class Ordered:
    """Selection and tour after the last round, and which reachable viewpoints are still allowed."""

    selection: Selection
    tour: Tour
    allowed: NDArray[np.bool_]
    dropped: int


@dataclass(frozen=True)
class Cover:
    """The exact minimum set cover over the allowed viewpoints (a bound on the selection's size)."""

    size: int | None
    proven: bool
    seconds: float


# --- stages ----------------------------------------------------------------------------------


def generate_and_filter(s: Setup, st: _Stages) -> Filtered:
    """Seeds on the surface, viewpoints at each distance, then the four filters.

    Runs in the ``generate_filter`` stage :func:`make_plan` opened (it builds the worlds first) and ends it.
    """
    from cellctl.planning.filters import camera_collision_filter, distance_filter, height_filter, occlusion_filter
    from cellctl.planning.seeds import sample_seeds
    from cellctl.planning.viewpoints import concat, generate_viewpoints, opening_viewpoints

    p, mesh = s.params, s.mesh
    pts, sfaces = sample_seeds(mesh, p.surface, p.seed_pct, s.rng)
    vp = generate_viewpoints(pts, mesh.normals[sfaces], sfaces, p.surface, p.distances)
    if p.surface == "internal" and p.opening_views:
        # after the fixed distances (a seed takes its first reachable rank): looking in through the
        # opening, where the fixed distances put the camera inside a deep cavity
        vp = concat(vp, opening_viewpoints(pts, sfaces, p.camera.dov, len(p.distances)))
    generated = len(vp)
    keep = height_filter(vp, mesh, float(max(rm.CAMERA_BOX_SIZE)))
    after_height = int(keep.sum())
    keep &= distance_filter(vp, s.T_bin_base[:3, 3], p.max_reach)
    after_distance = int(keep.sum())
    st.update(1, 3)
    idx = np.flatnonzero(keep)
    idx = idx[occlusion_filter(vp.subset(idx), mesh, s.rays)]
    after_occlusion = len(idx)
    st.update(2, 3)
    idx = idx[camera_collision_filter(vp.subset(idx), s.world)]
    st.end()
    return Filtered(vp.subset(idx), generated, len(pts), after_height, after_distance, after_occlusion, len(idx))


def reach(s: Setup, vp: Viewpoints, st: _Stages) -> Reachability:
    """IK + collision per viewpoint (and parking robustness); paper mode: an RRT* path from the start too.

    Runs in the ``reachability`` stage :func:`make_plan` opened (after checking the start
    configuration) and ends it.
    """
    from cellctl.planning.pathcost import JointPlanner
    from cellctl.planning.reach import reachability, robust_acceptor

    p = s.params
    verify = None
    planner = None
    accept = robust_acceptor(s.mesh, s.robot, s.T_bin_base, p)
    if p.mode == "paper":
        planner = JointPlanner(s.world)

        def verify(_i: int, q: NDArray[np.float64]) -> bool:
            ok, _, _ = planner.plan(s.q_start, q, "rrtstar", p.paper_budget_s, 0.0, fallback=p.paper_fallback)
            return ok

    reached = reachability(
        vp,
        s.robot,
        s.world,
        s.T_base_bin,
        s.q_start,
        p.n_roll,
        accept=accept,
        verify=verify,
        progress=lambda d, t: st.update(d, t),
    )
    st.end()
    if planner is None:
        return Reachability(reached, 0, 0)
    return Reachability(reached, planner.queries - planner.fallbacks, planner.fallbacks)


def measure(s: Setup, reached: Reached, st: _Stages) -> Visibility:
    """Which surface face each reachable viewpoint properly sees (matrix C), and the area all of them see."""
    from cellctl.planning.select import visible_area
    from cellctl.planning.visibility import measurability

    st.start("visibility", "visibility")
    C = measurability(reached.T, s.mesh, s.surf_faces, s.params.camera, s.rays, progress=lambda d, t: st.update(d, t))
    a = s.mesh.areas[s.surf_faces]
    seen = visible_area(C, a, np.arange(C.shape[1]))
    st.end()
    return Visibility(C, a, seen)


def select(s: Setup, vis: Visibility, allowed: NDArray[np.bool_], st: _Stages) -> Selection:
    """Greedy Area over the allowed viewpoints, then simulated annealing removes ``sa_pct`` % of it."""
    from cellctl.planning.select import greedy_area, simulated_annealing

    p = s.params
    st.start("selection", "selection")
    cols = np.flatnonzero(allowed)
    Cs = vis.C[:, cols]
    ga = cols[greedy_area(Cs, vis.face_areas)]
    st.update(1, 3)
    sa = simulated_annealing(Cs, vis.face_areas, np.searchsorted(cols, ga), p.sa_pct, s.rng, iterations=p.sa_iterations)
    st.end()
    return Selection(ga, cols[sa.selected], sa)


def paper_tour(s: Setup, reached: Reached, sel: NDArray[np.int64], st: _Stages) -> Tour:
    """The full path-cost matrix, every pair by RRT* with the fixed budget; ant colony + 2-opt on it."""
    from cellctl.planning.pathcost import path_cost_matrix
    from cellctl.planning.tour import ant_colony, two_opt

    p = s.params
    st.start("distance_matrix", "distance matrix")
    nodes_q = np.vstack([s.q_start[None], reached.q[sel]])
    pc = path_cost_matrix(
        nodes_q,
        s.world,
        "paper",
        budget_s=p.paper_budget_s,
        simplify_s=p.simplify_s,
        fallback=p.paper_fallback,
        progress=lambda d, t: st.update(d, t),
    )
    counts = {
        "matrix_pairs": len(nodes_q) * (len(nodes_q) - 1) // 2,
        "matrix_planned": pc.planned,
        "matrix_failed": pc.failed,
        "matrix_rrtconnect_fallbacks": pc.fallbacks,
    }
    st.end()
    st.start("ordering", "ant colony")
    order = two_opt(pc.D, ant_colony(pc.D, s.rng))
    st.end()

    def edge_path(i: int, j: int) -> NDArray[np.float64] | None:
        path = pc.paths.get((min(i, j), max(i, j)))
        return None if path is None else (path if i < j else path[::-1])

    return Tour(order, pc.D, _approaches(order, edge_path), counts)


def fast_tour(s: Setup, cache: Any, sel: NDArray[np.int64], st: _Stages) -> Tour:
    """Straight-line costs first, ant colony + 2-opt, then plan only the edges the tour uses and repair.

    Args:
        cache: the :class:`~cellctl.planning.pathcost.EdgeCache` over all reachable viewpoints
            (shared by the selection rounds, so an edge is planned once).
    """
    from cellctl.planning.pathcost import UNREACHABLE_COST
    from cellctl.planning.tour import ant_colony, two_opt

    nodes = [-1, *[int(k) for k in sel]]
    st.start("distance_matrix", "distance matrix")
    D, lazy = cache.matrix(nodes)
    st.end()
    st.start("ordering", "ant colony")
    order = two_opt(D, ant_colony(D, s.rng))
    st.end()
    for _round in range(MAX_TOUR_ROUNDS):
        edges = [(int(x), int(y)) for x, y in zip(order[:-1], order[1:], strict=True) if lazy[x, y]]
        if not edges:
            break
        st.start("distance_matrix", "tour edges")
        for k, (x, y) in enumerate(edges):
            cache.verify(nodes[x], nodes[y])
            st.update(k + 1, len(edges))
        D, lazy = cache.matrix(nodes)
        st.end()
        st.start("ordering", "2-opt repair")
        order = two_opt(D, order)  # repair the ant tour around edges that got dearer
        st.end()
    # rounds exhausted: plan what is left of the final tour without re-ordering it, so
    # every reported edge cost is a real motion (or a failure)
    for x, y in zip(order[:-1], order[1:], strict=True):
        if lazy[x, y]:
            cache.verify(nodes[int(x)], nodes[int(y)])
    D, lazy = cache.matrix(nodes)
    upper = np.triu_indices(len(nodes), 1)
    counts = {
        "matrix_pairs": len(nodes) * (len(nodes) - 1) // 2,
        "matrix_straight": int(np.sum(~lazy[upper] & (D[upper] < UNREACHABLE_COST))),
        "matrix_planned": cache.planned,
        "matrix_failed": cache.failed,
        "tour_failed_edges": int(sum(D[x, y] >= UNREACHABLE_COST for x, y in zip(order[:-1], order[1:], strict=True))),
    }
    approaches = _approaches(order, lambda i, j: cache.path(nodes[i], nodes[j]))
    return Tour(order, D, approaches, counts, tuple(cache.isolated(nodes)))


def _approaches(
    order: NDArray[np.int64], edge_path: Callable[[int, int], NDArray[np.float64] | None]
) -> tuple[NDArray[np.float64] | None, ...]:
    return tuple(edge_path(int(order[rank]), int(node)) for rank, node in enumerate(order[1:]))


def select_and_order(s: Setup, reached: Reached, vis: Visibility, st: _Stages) -> Ordered:
    """Selection then tour; fast mode drops viewpoints no motion connects and selects again (≤ 4 rounds)."""
    from cellctl.planning.pathcost import EdgeCache

    p = s.params
    cache = None
    if p.mode == "fast":
        cache = EdgeCache(reached.q, s.q_start, s.world, p.fallback_budget_s, p.simplify_s)
    allowed = np.ones(vis.C.shape[1], dtype=bool)
    dropped = 0
    for _attempt in range(MAX_SELECT_ROUNDS):
        selection = select(s, vis, allowed, st)
        if cache is None:
            tour = paper_tour(s, reached, selection.selected, st)
            break
        tour = fast_tour(s, cache, selection.selected, st)
        if not tour.isolated:
            break
        # viewpoints no motion could connect are not reachable after all: drop them, re-select
        allowed[list(tour.isolated)] = False
        dropped += len(tour.isolated)
    return Ordered(selection, tour, allowed, dropped)


def exact_cover(vis: Visibility, allowed: NDArray[np.bool_], p: PlanParams, st: _Stages) -> Cover:
    """The smallest set of allowed viewpoints seeing everything they all see (HiGHS, time-limited)."""
    from cellctl.planning.select import min_set_cover

    st.start("selection", "exact cover")
    n_opt, proven, seconds = min_set_cover(vis.C[:, allowed], p.cover_time_limit_s)
    st.end()
    return Cover(n_opt, proven, seconds)


# --- assembly ----------------------------------------------------------------------------


@dataclass(frozen=True)
class _Header:
    plan_id: str
    created: str
    bin_type: str
    t0: float


def assemble(
    s: Setup,
    head: _Header,
    st: _Stages,
    filt: Filtered,
    found: Reachability | None = None,
    vis: Visibility | None = None,
    ordered: Ordered | None = None,
    cover: Cover | None = None,
    reason: str | None = None,
) -> Plan:
    """The plan from the stage results so far (an empty plan with ``reason`` when a stage left nothing)."""
    from cellctl.planning.select import visible_area
    from cellctl.planning.tour import path_cost

    mesh, p, sf = s.mesh, s.params, s.surf_faces
    reached = found.reached if found is not None else None
    stage = dict(
        seeds=filt.seeds,
        after_height=filt.after_height,
        after_distance=filt.after_distance,
        after_occlusion=filt.after_occlusion,
        after_camera_collision=filt.after_camera_collision,
    )
    counts = dict(generated=filt.generated, filtered=len(filt.vp))
    area: dict[str, Any] = dict(mesh_m2=float(mesh.areas[sf].sum()))
    reachable: tuple[ReachableViewpoint, ...] = ()
    viewpoints: tuple[PlannedViewpoint, ...] = ()
    tour_cost, coverage, sa, exact_s = 0.0, 0.0, None, None
    if found is not None and reached is not None:
        counts["reachable"] = len(reached.index)
        stage.update(
            reach_tried=reached.tried,
            reach_checks=reached.checks,
            reach_planner_queries=found.planner_queries,
            reach_rrtconnect_fallbacks=found.rrtconnect_fallbacks,
        )
    if vis is not None and reached is not None:
        area["visible_all_m2"] = vis.visible_all_m2
        allowed = ordered.allowed if ordered is not None else np.ones(len(reached.index), dtype=bool)
        reachable = tuple(
            ReachableViewpoint(
                T_bin_cam=_ro(reached.T[k]),
                q=_ro(reached.q[k]),
                faces=_ro(sf[vis.C[:, k]], np.int64),
                seed_face=int(filt.vp.seed_face[reached.index[k]]),
            )
            for k in range(len(reached.index))
            if allowed[k]
        )
    if ordered is not None and cover is not None and vis is not None and reached is not None:
        sel, tour = ordered.selection, ordered.tour
        stage.update(tour.counts)
        stage.update(dropped_unconnected=ordered.dropped, optimal_cover_proven=int(cover.proven))
        counts.update(
            reachable=int(ordered.allowed.sum()),
            greedy=len(sel.greedy),
            annealed=len(sel.selected),
            optimal_cover=cover.size,
        )
        exact_s = cover.seconds
        seen_sel = visible_area(vis.C, vis.face_areas, sel.selected)
        area.update(
            visible_selected_m2=seen_sel,
            loss_pct=100.0 * (1.0 - seen_sel / vis.visible_all_m2),
            greedy_loss_pct=100.0 * (1.0 - visible_area(vis.C, vis.face_areas, sel.greedy) / vis.visible_all_m2),
        )
        tour_cost = path_cost(tour.D, tour.order)
        viewpoints = tuple(
            _planned(s, filt, reached, vis, tour, rank, int(sel.selected[node - 1]))
            for rank, node in enumerate(tour.order[1:])
        )
        coverage = seen_sel / area["mesh_m2"] if area["mesh_m2"] > 0 else 0.0
        sa = SAStats(iterations=sel.sa.iterations, accepted=sel.sa.accepted)
    times = StageTimes(**st.times, exact_cover_s=exact_s, total=time.perf_counter() - head.t0)
    return Plan(
        plan_id=head.plan_id,
        created=head.created,
        bin_type=head.bin_type,
        mesh_sha256=mesh.sha256,
        robot_model_id=s.robot.model_id(),
        surface=p.surface,
        mode=p.mode,
        params=p,
        base=BasePose(T_bin_base=_ro(s.T_bin_base), T_base_bin=_ro(s.T_base_bin)),
        q_start=_ro(s.q_start),
        counts=CandidateCounts(**counts),
        stage_counts=StageCounts(**stage),
        area=AreaStats(**area),
        times_s=times,
        tour_cost=tour_cost,
        coverage=coverage,
        viewpoints=viewpoints,
        reachable=reachable,
        reason=reason,
        mesh_faces=int(len(mesh.faces)),
        surface_faces=int(len(sf)),
        sa=sa,
    )


def _planned(
    s: Setup, filt: Filtered, reached: Reached, vis: Visibility, tour: Tour, rank: int, k: int
) -> PlannedViewpoint:
    """The tour's ``rank``-th viewpoint, reachable candidate ``k``."""
    path = tour.approaches[rank]
    prev, node = int(tour.order[rank]), int(tour.order[rank + 1])
    return PlannedViewpoint(
        index=rank,
        candidate=k,
        T_bin_cam=_ro(reached.T[k]),
        T_base_cam=_ro(s.T_base_bin @ reached.T[k]),
        q=_ro(reached.q[k]),
        roll=float(reached.roll[k]),
        faces=_ro(s.surf_faces[vis.C[:, k]], np.int64),
        seed_face=int(filt.vp.seed_face[reached.index[k]]),
        approach=_ro(path[1:-1] if path is not None else np.zeros((0, 6))),
        cost_from_prev=float(tour.D[prev, node]),
    )


# --- the pipeline ------------------------------------------------------------------------


def make_plan(
    mesh: BinMesh,
    T_bin_base: NDArray[np.float64],
    params: PlanParams,
    robot: RobotModel,
    *,
    bin_type: str | None = None,
    progress: ProgressFn | None = None,
    show_bars: bool = False,
) -> Plan:
    """Run the whole pipeline, stage by stage (see the module's table).

    An empty candidate set at any stage gives a plan with no viewpoints and ``reason`` set;
    it is not an exception, because "nothing is reachable from here" is an answer.

    Raises:
        PlanningError: bad parameters or a mesh that has no faces on the requested surface.
    """
    params.check()
    t0 = time.perf_counter()
    head = _Header(uuid.uuid4().hex[:12], time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), bin_type or mesh.name, t0)
    T_bin_base = np.asarray(T_bin_base, dtype=np.float64)
    st = _Stages(progress, show_bars)
    # the collision world is booked under generate_filter: a mesh's first plan builds its distance grid here
    st.start("generate_filter", "generate+filter")
    s = Setup(
        mesh=mesh,
        robot=robot,
        params=params,
        T_bin_base=T_bin_base,
        T_base_bin=invert(T_bin_base),
        q_start=np.asarray(params.q_start if params.q_start is not None else robot.q_home, dtype=np.float64),
        surf_faces=np.flatnonzero(mesh.surface_mask(params.surface)),
        world=PlanningWorld(mesh, robot, T_bin_base, margin=params.margin),
        rays=RayCaster(mesh.vertices, mesh.faces),
        rng=np.random.default_rng(params.seed),
    )
    filt = generate_and_filter(s, st)
    if len(filt.vp) == 0:
        return assemble(s, head, st, filt, reason=_nothing_filtered(filt, params))
    st.start("reachability", "reachability")
    if not s.world.robot_free(s.q_start)[0]:
        st.end()
        q = np.round(s.q_start, 3).tolist()
        return assemble(s, head, st, filt, reason=f"the start configuration {q} is in collision with the bin/floor")
    reached = reach(s, filt.vp, st)
    if len(reached.reached.index) == 0:
        return assemble(
            s,
            head,
            st,
            filt,
            reached,
            reason=f"none of the {len(filt.vp)} filtered viewpoints is reachable from base pose "
            f"{np.round(T_bin_base[:3, 3], 3).tolist()} (IK within joint limits + collision-free)",
        )
    vis = measure(s, reached.reached, st)
    if vis.visible_all_m2 <= 0:
        reason = "no face of the surface is properly visible from any reachable viewpoint"
        return assemble(s, head, st, filt, reached, vis, reason=reason)
    ordered = select_and_order(s, reached.reached, vis, st)
    cover = exact_cover(vis, ordered.allowed, params, st)
    return assemble(s, head, st, filt, reached, vis, ordered, cover)


def _nothing_filtered(filt: Filtered, p: PlanParams) -> str:
    return (
        "no viewpoint survived the filters "
        f"(height {filt.after_height}, distance {filt.after_distance}, "
        f"occlusion {filt.after_occlusion}, camera collision 0 of {filt.generated}); "
        f"is the robot base within {p.max_reach} m of the {p.surface} surface?"
    )
