"""The offline planning pipeline: mesh + base pose → ordered, reachable viewpoints.

Stages (paper §IV-A) and the ``times_s`` key each is booked under:

==============================  =================
seeds, viewpoints, 4 filters    generate_filter
IK + collision (+ RRT* paper)   reachability
visible faces, matrix C         visibility
Greedy Area, SA, exact cover    selection
path-cost matrix                distance_matrix
ant colony + 2-opt              ordering
==============================  =================
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import PlanningError
from cellctl.geometry import robot_model as rm
from cellctl.geometry.transforms import invert, rotation_about, transform_from
from cellctl.planning.mesh import BinMesh
from cellctl.planning.robot import RobotModel
from cellctl.planning.visibility import CameraModel

__all__ = ["PlanParams", "ProgressFn", "base_pose_from_xyz_yaw", "make_plan"]

ProgressFn = Callable[[str, float, str], None]
"""``progress(stage, fraction 0..1, message)``."""

MAX_TOUR_ROUNDS = 12  # fast mode: plan-the-tour's-edges / re-order rounds
MAX_SELECT_ROUNDS = 4  # fast mode: re-select after dropping viewpoints no motion connects


def robust_acceptor(
    mesh: BinMesh, robot: RobotModel, T_bin_base: NDArray[np.float64], params: PlanParams
) -> Callable[[int, NDArray[np.float64]], bool] | None:
    """``accept(i, q)``: does configuration ``q`` survive the base parking ±robust_m / ±robust_deg off?

    For each of six parking errors E (±x, ±y, ±yaw in the base frame) the camera must reach the
    same bin-relative pose ``inv(E) · fk_cam(q)`` with an IK solution within 0.5 rad of ``q``
    per joint (what the cache adjustment accepts) and that is collision-free with the bin at
    its moved pose. Returns None when disabled.
    """
    if params.robust_m <= 0 and params.robust_deg <= 0:
        return None
    from cellctl.geometry.transforms import transform_from_xyz_rpy
    from cellctl.planning.collision import CollisionWorld
    from cellctl.planning.reach import wrap_towards

    t, r = params.robust_m, np.radians(params.robust_deg)
    errors = [
        transform_from_xyz_rpy(x, (0.0, 0.0, a))
        for x, a in (
            ((t, 0, 0), 0.0),
            ((-t, 0, 0), 0.0),
            ((0, t, 0), 0.0),
            ((0, -t, 0), 0.0),
            ((0, 0, 0), r),
            ((0, 0, 0), -r),
        )
    ]
    worlds = [CollisionWorld(mesh, robot, T_bin_base @ E, margin=params.margin) for E in errors]
    inv_errors = [invert(E) for E in errors]

    def accept(_i: int, q: NDArray[np.float64]) -> bool:
        T_base_cam = robot.fk_cam(q[None])[0]
        Qs = []
        for Ei in inv_errors:
            S = robot.ik_cam(Ei @ T_base_cam)
            if len(S) == 0:
                return False
            S = wrap_towards(S, q, robot)
            best = S[np.argmin(np.abs(S - q).max(axis=1))]
            if np.abs(best - q).max() > 0.5:
                return False
            Qs.append(best)
        return all(bool(w.robot_free(qq)[0]) for w, qq in zip(worlds, Qs, strict=True))

    return accept


STAGES = ("generate_filter", "reachability", "visibility", "selection", "distance_matrix", "ordering")


@dataclass
class PlanParams:
    """Everything that shapes a plan (paper Table 1 defaults). Lengths m, angles rad unless named _deg.

    Attributes:
        surface: "external" or "internal".
        seed_pct: p_SP, % of the surface's faces used as seeds.
        mode: "fast" or "paper".
        seed: RNG seed (seeds, SA, ACO).
        distances: d_0 … d_{D−1} from the seed, preference order.
        max_reach: distance filter radius around the robot base (r̄).
        n_roll: rolls about the optical axis tried by reachability.
        sa_pct: p_SA, % of the Greedy Area set SA removes (0: skip SA).
        sa_iterations: SA steps.
        margin: collision clearance.
        camera: intrinsics and usable ranges.
        paper_budget_s: RRT* time per query in paper mode (the paper's MoveIt used ~1.2 s).
        paper_fallback: paper mode: when RRT* ends its budget without a solution, RRTConnect
            decides feasibility. Our RRT* calls Python collision checks and runs ~20× fewer
            iterations per second than the paper's C++ MoveIt/FCL; alone it rejects about half
            of the goals RRTConnect reaches in 0.03 s, which would compare coverage against a
            handicapped baseline. The RRT* budget (the paper's cost) is still spent in full.
        fallback_budget_s: RRTConnect limit for colliding straight motions in fast mode.
        simplify_s: simplification limit per planned path.
        cover_time_limit_s: HiGHS limit for the exact set-cover bound.
        q_start: the robot's current configuration (tour start); None → the robot's home.
        robust_m, robust_deg: a viewpoint is kept only if it stays reachable (IK next to its
            joints, same arm shape, collision-free) when the base parks this far off in x, y
            and yaw; so a cached plan can be adjusted to the next park instead of replanned.
            0 disables the check.
    """

    surface: str = "external"
    seed_pct: float = 10.0
    mode: str = "fast"
    seed: int = 0
    distances: tuple[float, ...] = (0.3, 0.4)
    max_reach: float = 1.3
    n_roll: int = 12
    sa_pct: float = 15.0
    sa_iterations: int = 4000
    margin: float = 0.005
    camera: CameraModel = field(default_factory=CameraModel)
    paper_budget_s: float = 1.0
    paper_fallback: bool = True
    fallback_budget_s: float = 0.2
    simplify_s: float = 0.05
    cover_time_limit_s: float = 5.0
    q_start: tuple[float, ...] | None = None
    robust_m: float = 0.04
    robust_deg: float = 2.0

    def check(self) -> None:
        """Raise PlanningError naming the first bad parameter."""
        if self.surface not in ("external", "internal"):
            raise PlanningError(f"surface {self.surface!r} is unknown; expected 'external' or 'internal'")
        if self.mode not in ("fast", "paper"):
            raise PlanningError(f"mode {self.mode!r} is unknown; expected 'fast' or 'paper'")
        if not 0 < self.seed_pct <= 100:
            raise PlanningError(f"seed_pct {self.seed_pct!r} must be in (0, 100]")
        if not 0 <= self.sa_pct < 100:
            raise PlanningError(f"sa_pct {self.sa_pct!r} must be in [0, 100)")
        if not self.distances or any(d <= 0 for d in self.distances):
            raise PlanningError(f"distances {list(self.distances)} must be positive metres")
        if self.n_roll < 1:
            raise PlanningError(f"n_roll {self.n_roll!r} must be >= 1")
        if self.q_start is not None and len(self.q_start) != 6:
            raise PlanningError(f"q_start must have 6 joint angles, got {len(self.q_start)}")

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["distances"] = list(self.distances)
        d["camera"]["dov"] = list(self.camera.dov)
        d["q_start"] = list(self.q_start) if self.q_start is not None else None
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> PlanParams:
        d = dict(d)
        cam = dict(d.pop("camera", {}))
        if "dov" in cam:
            cam["dov"] = tuple(cam["dov"])
        d["distances"] = tuple(d.get("distances", (0.3, 0.4)))
        if d.get("q_start") is not None:
            d["q_start"] = tuple(d["q_start"])
        return cls(camera=CameraModel(**cam), **d)


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


def make_plan(
    mesh: BinMesh,
    T_bin_base: NDArray[np.float64],
    params: PlanParams,
    robot: RobotModel,
    *,
    bin_type: str | None = None,
    progress: ProgressFn | None = None,
    show_bars: bool = False,
) -> dict[str, Any]:
    """Run the whole pipeline; return the plan as a JSON-ready dict (see :mod:`cellctl.planning.planfile`).

    An empty candidate set at any stage gives a plan with no viewpoints and ``reason`` set;
    it is not an exception, because "nothing is reachable from here" is an answer.

    Raises:
        PlanningError: bad parameters or a mesh that has no faces on the requested surface.
    """
    from cellctl.planning.collision import CollisionWorld
    from cellctl.planning.filters import camera_collision_filter, distance_filter, height_filter, occlusion_filter
    from cellctl.planning.pathcost import UNREACHABLE_COST, EdgeCache, JointPlanner, path_cost_matrix
    from cellctl.planning.raycast import RayCaster
    from cellctl.planning.reach import reachability
    from cellctl.planning.seeds import sample_seeds
    from cellctl.planning.select import greedy_area, min_set_cover, simulated_annealing, visible_area
    from cellctl.planning.tour import ant_colony, path_cost, two_opt
    from cellctl.planning.viewpoints import generate_viewpoints
    from cellctl.planning.visibility import measurability

    params.check()
    t_all = time.perf_counter()
    T_bin_base = np.asarray(T_bin_base, dtype=np.float64)
    T_base_bin = invert(T_bin_base)
    rng = np.random.default_rng(params.seed)
    st = _Stages(progress, show_bars)
    q_start = np.asarray(params.q_start if params.q_start is not None else robot.q_home, dtype=np.float64)
    surf_faces = np.flatnonzero(mesh.surface_mask(params.surface))
    counts: dict[str, Any] = {k: 0 for k in ("generated", "filtered", "reachable", "greedy", "annealed")}
    counts["optimal_cover"] = None
    stage_counts: dict[str, int] = {}
    area = {
        "mesh_m2": float(mesh.areas[surf_faces].sum()),
        "visible_all_m2": 0.0,
        "visible_selected_m2": 0.0,
        "loss_pct": 0.0,
    }
    plan: dict[str, Any] = {
        "plan_id": uuid.uuid4().hex[:12],
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "bin_type": bin_type or mesh.name,
        "mesh_sha256": mesh.sha256,
        "robot_model_id": robot.model_id(),
        "surface": params.surface,
        "mode": params.mode,
        "params": params.to_json(),
        "T_bin_base": T_bin_base.tolist(),
        "T_base_bin": T_base_bin.tolist(),
        "q_start": q_start.tolist(),
        "counts": counts,
        "stage_counts": stage_counts,
        "area": area,
        "times_s": st.times,
        "tour_cost": 0.0,
        "coverage": 0.0,
        "viewpoints": [],
        "reachable": [],
        "reason": None,
        "mesh_faces": int(len(mesh.faces)),
        "surface_faces": int(len(surf_faces)),
    }

    def finish(reason: str | None) -> dict[str, Any]:
        plan["reason"] = reason
        st.times["total"] = time.perf_counter() - t_all
        return plan

    # --- generation + filters ---------------------------------------------------------
    st.start("generate_filter", "generate+filter")
    pts, sfaces = sample_seeds(mesh, params.surface, params.seed_pct, rng)
    vp = generate_viewpoints(pts, mesh.normals[sfaces], sfaces, params.surface, params.distances)
    counts["generated"] = len(vp)
    stage_counts["seeds"] = len(pts)
    world = CollisionWorld(mesh, robot, T_bin_base, margin=params.margin)
    rays = RayCaster(mesh.vertices, mesh.faces)
    cam_dim = float(max(rm.CAMERA_BOX_SIZE))
    keep = height_filter(vp, mesh, cam_dim)
    stage_counts["after_height"] = int(keep.sum())
    keep &= distance_filter(vp, T_bin_base[:3, 3], params.max_reach)
    stage_counts["after_distance"] = int(keep.sum())
    st.update(1, 3)
    idx = np.flatnonzero(keep)
    idx = idx[occlusion_filter(vp.subset(idx), mesh, rays)]
    stage_counts["after_occlusion"] = len(idx)
    st.update(2, 3)
    idx = idx[camera_collision_filter(vp.subset(idx), world)]
    stage_counts["after_camera_collision"] = len(idx)
    vp = vp.subset(idx)
    counts["filtered"] = len(vp)
    st.end()
    if len(vp) == 0:
        return finish(
            "no viewpoint survived the filters "
            f"(height {stage_counts['after_height']}, distance {stage_counts['after_distance']}, "
            f"occlusion {stage_counts['after_occlusion']}, camera collision 0 of {counts['generated']}); "
            f"is the robot base within {params.max_reach} m of the {params.surface} surface?"
        )

    # --- reachability ---------------------------------------------------------------------
    st.start("reachability", "reachability")
    verify = None
    planner = None
    accept = robust_acceptor(mesh, robot, T_bin_base, params)
    if params.mode == "paper":
        planner = JointPlanner(world)

        def verify(_i: int, q: NDArray[np.float64]) -> bool:
            ok, _, _ = planner.plan(q_start, q, "rrtstar", params.paper_budget_s, 0.0, fallback=params.paper_fallback)
            return ok

    if not world.robot_free(q_start)[0]:
        st.end()
        return finish(f"the start configuration {np.round(q_start, 3).tolist()} is in collision with the bin/floor")
    reached = reachability(
        vp,
        robot,
        world,
        T_base_bin,
        q_start,
        params.n_roll,
        accept=accept,
        verify=verify,
        progress=lambda d, t: st.update(d, t),
    )
    counts["reachable"] = len(reached.index)
    stage_counts["reach_tried"] = reached.tried
    stage_counts["reach_checks"] = reached.checks
    stage_counts["reach_planner_queries"] = planner.queries - planner.fallbacks if planner else 0
    stage_counts["reach_rrtconnect_fallbacks"] = planner.fallbacks if planner else 0
    st.end()
    if len(reached.index) == 0:
        return finish(
            f"none of the {len(vp)} filtered viewpoints is reachable from base pose "
            f"{np.round(T_bin_base[:3, 3], 3).tolist()} (IK within joint limits + collision-free)"
        )

    # --- visibility ---------------------------------------------------------------------------
    st.start("visibility", "visibility")
    C = measurability(reached.T, mesh, surf_faces, params.camera, rays, progress=lambda d, t: st.update(d, t))
    a = mesh.areas[surf_faces]
    area["visible_all_m2"] = visible_area(C, a, np.arange(C.shape[1]))
    st.end()
    plan["reachable"] = [
        {
            "T_bin_cam": reached.T[k].tolist(),
            "q": reached.q[k].tolist(),
            "faces": surf_faces[C[:, k]].tolist(),
            "seed_face": int(vp.seed_face[reached.index[k]]),
        }
        for k in range(len(reached.index))
    ]
    if area["visible_all_m2"] <= 0:
        return finish("no face of the surface is properly visible from any reachable viewpoint")

    # --- selection ----------------------------------------------------------------------------
    jp_cache = None
    if params.mode == "fast":
        jp_cache = EdgeCache(reached.q, q_start, world, params.fallback_budget_s, params.simplify_s)
    allowed = np.ones(C.shape[1], dtype=bool)
    dropped: list[int] = []
    for _attempt in range(MAX_SELECT_ROUNDS):
        # --- selection (over the viewpoints still allowed) ---------------------------------
        st.start("selection", "selection")
        cols = np.flatnonzero(allowed)
        Cs = C[:, cols]
        ga = cols[greedy_area(Cs, a)]
        st.update(1, 3)
        sa = simulated_annealing(Cs, a, np.searchsorted(cols, ga), params.sa_pct, rng, iterations=params.sa_iterations)
        sel = cols[sa.selected]
        st.end()
        if params.mode == "paper":
            # --- full matrix, every pair by RRT* with the fixed budget -----------------------
            st.start("distance_matrix", "distance matrix")
            nodes_q = np.vstack([q_start[None], reached.q[sel]])
            pc = path_cost_matrix(
                nodes_q,
                world,
                "paper",
                budget_s=params.paper_budget_s,
                simplify_s=params.simplify_s,
                fallback=params.paper_fallback,
                progress=lambda d, t: st.update(d, t),
            )
            stage_counts["matrix_pairs"] = len(nodes_q) * (len(nodes_q) - 1) // 2
            stage_counts["matrix_planned"] = pc.planned
            stage_counts["matrix_failed"] = pc.failed
            stage_counts["matrix_rrtconnect_fallbacks"] = pc.fallbacks
            st.end()
            st.start("ordering", "ant colony")
            order = two_opt(pc.D, ant_colony(pc.D, rng))
            st.end()
            D = pc.D

            def edge_path(i: int, j: int, pc=pc) -> NDArray[np.float64] | None:  # noqa: ANN001
                p = pc.paths.get((min(i, j), max(i, j)))
                return None if p is None else (p if i < j else p[::-1])

            break
        # --- fast: straight lines now, plan only the edges the tour uses ----------------------
        nodes = [-1, *[int(k) for k in sel]]
        st.start("distance_matrix", "distance matrix")
        D, lazy = jp_cache.matrix(nodes)
        st.end()
        st.start("ordering", "ant colony")
        order = two_opt(D, ant_colony(D, rng))
        st.end()
        for _round in range(MAX_TOUR_ROUNDS):
            edges = [(int(x), int(y)) for x, y in zip(order[:-1], order[1:], strict=True) if lazy[x, y]]
            if not edges:
                break
            st.start("distance_matrix", "tour edges")
            for k, (x, y) in enumerate(edges):
                jp_cache.verify(nodes[x], nodes[y])
                st.update(k + 1, len(edges))
            D, lazy = jp_cache.matrix(nodes)
            st.end()
            st.start("ordering", "2-opt repair")
            order = two_opt(D, order)  # repair the ant tour around edges that got dearer
            st.end()
        # rounds exhausted: plan what is left of the final tour without re-ordering it, so
        # every reported edge cost is a real motion (or a failure)
        for x, y in zip(order[:-1], order[1:], strict=True):
            if lazy[x, y]:
                jp_cache.verify(nodes[int(x)], nodes[int(y)])
        D, lazy = jp_cache.matrix(nodes)
        bad = jp_cache.isolated(nodes)
        stage_counts["matrix_pairs"] = len(nodes) * (len(nodes) - 1) // 2
        stage_counts["matrix_straight"] = int(
            np.sum(~lazy[np.triu_indices(len(nodes), 1)] & (D[np.triu_indices(len(nodes), 1)] < UNREACHABLE_COST))
        )
        stage_counts["matrix_planned"] = jp_cache.planned
        stage_counts["matrix_failed"] = jp_cache.failed
        stage_counts["tour_failed_edges"] = int(
            sum(D[x, y] >= UNREACHABLE_COST for x, y in zip(order[:-1], order[1:], strict=True))
        )

        def edge_path(i: int, j: int, nodes=nodes) -> NDArray[np.float64] | None:  # noqa: ANN001
            return jp_cache.path(nodes[i], nodes[j])

        if not bad:
            break
        # viewpoints no motion could connect are not reachable after all: drop them, re-select
        allowed[bad] = False
        dropped += bad
    stage_counts["dropped_unconnected"] = len(dropped)
    plan["reachable"] = [r for k, r in enumerate(plan["reachable"]) if allowed[k]]
    counts["reachable"] = int(allowed.sum())
    counts["greedy"] = len(ga)
    counts["annealed"] = len(sel)
    st.start("selection", "exact cover")
    n_opt, proven, t_cover = min_set_cover(C[:, allowed], params.cover_time_limit_s)
    st.end()
    counts["optimal_cover"] = n_opt
    stage_counts["optimal_cover_proven"] = int(proven)
    plan["times_s"]["exact_cover_s"] = t_cover
    area["visible_selected_m2"] = visible_area(C, a, sel)
    area["loss_pct"] = 100.0 * (1.0 - area["visible_selected_m2"] / area["visible_all_m2"])
    area["greedy_loss_pct"] = 100.0 * (1.0 - visible_area(C, a, ga) / area["visible_all_m2"])
    plan["tour_cost"] = path_cost(D, order)

    vps = []
    for rank, node in enumerate(order[1:]):
        k = int(sel[node - 1])
        prev = int(order[rank])
        path = edge_path(prev, int(node))
        T_bin_cam = reached.T[k]
        vps.append(
            {
                "index": rank,
                "candidate": k,
                "T_bin_cam": T_bin_cam.tolist(),
                "T_base_cam": (T_base_bin @ T_bin_cam).tolist(),
                "q": reached.q[k].tolist(),
                "roll": float(reached.roll[k]),
                "faces": surf_faces[C[:, k]].tolist(),
                "seed_face": int(vp.seed_face[reached.index[k]]),
                "approach": path[1:-1].tolist() if path is not None else [],
                "cost_from_prev": float(D[prev, node]),
            }
        )
    plan["viewpoints"] = vps
    plan["coverage"] = area["visible_selected_m2"] / area["mesh_m2"] if area["mesh_m2"] > 0 else 0.0
    plan["sa"] = {"iterations": sa.iterations, "accepted": sa.accepted}
    return finish(None)
