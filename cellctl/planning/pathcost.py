"""Path-cost matrix between configurations (paper §IV-A3) and the OMPL wrapper behind it.

``fast``: the straight joint-space motion is checked first (batched for all pairs at once);
only pairs whose straight motion collides go to OMPL RRTConnect + bounded simplification.
``paper``: every pair is planned with RRT* and a fixed time budget, like the paper's
MoveIt/OMPL set-up, whose per-query cost is that budget (notes/planning.md §1).
Costs are joint-space path lengths (rad).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from cellctl.planning.collision import PlanningWorld

__all__ = ["EdgeCache", "JointPlanner", "PathCosts", "path_cost_matrix"]

PLANNER_RANGE_RAD = 0.5  # RRT extension length (joint space), rad
UNREACHABLE_COST = 1.0e3  # rad; a pair no planner connected is avoided by the tour, not fatal


class JointPlanner:
    """OMPL 2.x (nanobind) joint-space planner on a :class:`PlanningWorld`.

    Motion validity uses the world's batched straight-line check (a custom
    ``MotionValidator``), so one OMPL edge costs one vectorised call, not dozens.

    Args:
        world: collision world.
        max_step: joint-space interpolation step for edge checks, rad.
    """

    def __init__(self, world: PlanningWorld, max_step: float = 0.02) -> None:
        from ompl import base as ob
        from ompl import util as ou

        ou.setLogLevel(ou.LogLevel.LOG_ERROR)
        self.world = world
        self.max_step = max_step
        robot = world.robot
        self.space = ob.RealVectorStateSpace(6)
        bounds = ob.RealVectorBounds(6)
        for i in range(6):
            bounds.setLow(i, float(robot.q_min[i]))
            bounds.setHigh(i, float(robot.q_max[i]))
        self.space.setBounds(bounds)
        self.queries = 0
        self.fallbacks = 0  # RRT* queries that RRTConnect had to decide

    def _setup(self):  # ompl SimpleSetup
        from ompl import base as ob
        from ompl import geometric as og

        world, step = self.world, self.max_step
        ss = og.SimpleSetup(self.space)
        si = ss.getSpaceInformation()

        def valid(s) -> bool:  # OMPL state
            return bool(world.robot_free(np.array([s[i] for i in range(6)]))[0])

        class _Motion(ob.MotionValidator):
            def checkMotion(self, s1, s2, *args) -> bool:  # OMPL API
                a = np.array([s1[i] for i in range(6)])
                b = np.array([s2[i] for i in range(6)])
                return bool(world.motion_free(a, b, step)[0])

        ss.setStateValidityChecker(valid)
        mv = _Motion(si)
        si.setMotionValidator(mv)
        return ss, si, mv

    def plan(
        self,
        q_a: NDArray[np.float64],
        q_b: NDArray[np.float64],
        planner: str,
        budget_s: float,
        simplify_s: float,
        fallback: bool = False,
    ) -> tuple[bool, float, NDArray[np.float64]]:
        """Plan ``q_a → q_b``.

        Args:
            planner: "rrtconnect" (stops at the first solution) or "rrtstar" (anytime: uses
                the whole budget, as in the paper).
            budget_s: planning time limit, s.
            simplify_s: time limit of the path simplification, s (0: none).
            fallback: RRT* only: when the budget ends without an exact solution, let
                RRTConnect (same budget) decide feasibility (see PlanParams.paper_fallback).

        Returns:
            ``(found, length_rad, path (K, 6))``.
        """
        from ompl import base as ob
        from ompl import geometric as og

        self.queries += 1
        ss, si, mv = self._setup()
        s0, s1 = self.space.allocState(), self.space.allocState()
        for i in range(6):
            s0[i] = float(q_a[i])
            s1[i] = float(q_b[i])
        ss.setStartAndGoalStates(s0, s1)
        if planner == "rrtstar":
            ss.setOptimizationObjective(ob.PathLengthOptimizationObjective(si))
            pl = og.RRTstar(si)
        else:
            pl = og.RRTConnect(si)
        # OMPL's default range is 20 % of the space extent (~6 rad here): every extension is a
        # long, mostly colliding motion check; short steps solve the narrow passages near the bin
        pl.setRange(PLANNER_RANGE_RAD)
        ss.setPlanner(pl)
        ss.solve(float(budget_s))
        if not ss.haveExactSolutionPath():
            ss.clear()
            if planner == "rrtstar" and fallback:
                self.fallbacks += 1
                return self.plan(q_a, q_b, "rrtconnect", budget_s, simplify_s)
            return False, float("inf"), np.zeros((0, 6))
        if simplify_s > 0:
            ss.simplifySolution(float(simplify_s))
        p = ss.getSolutionPath()
        path = np.array([[p.getState(k)[i] for i in range(6)] for k in range(p.getStateCount())])
        ss.clear()
        length = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
        return True, length, path


@dataclass
class PathCosts:
    """Symmetric cost matrix and how each entry was obtained.

    Attributes:
        D: (n, n) joint-space path lengths, rad (``UNREACHABLE_COST`` + distance if none found).
        straight: (n, n) True where the straight joint motion is collision-free.
        planned: number of pairs sent to OMPL.
        failed: pairs OMPL could not connect.
        paths: planned (non-straight) paths by pair (i, j), i < j, joint waypoints (K, 6).
    """

    D: NDArray[np.float64]
    straight: NDArray[np.bool_]
    planned: int = 0
    failed: int = 0
    fallbacks: int = 0
    paths: dict[tuple[int, int], NDArray[np.float64]] = field(default_factory=dict)


LAZY_FACTOR = 1.5  # estimated detour of a colliding pair relative to the straight joint distance


def path_cost_matrix(
    Q: NDArray[np.float64],
    world: PlanningWorld,
    mode: str = "fast",
    *,
    budget_s: float = 1.0,
    simplify_s: float = 0.2,
    max_step: float = 0.02,
    fallback: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> PathCosts:
    """Pairwise path costs between configurations ``Q`` (n, 6).

    Args:
        mode: "fast" (straight line, RRTConnect where it collides) or "paper" (RRT* with
            ``budget_s`` for every pair).
        budget_s: planner time limit per query, s.
        simplify_s: simplification time limit per planned path, s.
    """
    n = len(Q)
    D = np.zeros((n, n))
    iu, ju = np.triu_indices(n, 1)
    direct = np.linalg.norm(Q[ju] - Q[iu], axis=1)
    straight = np.zeros((n, n), dtype=bool)
    np.fill_diagonal(straight, True)
    out = PathCosts(D=D, straight=straight)
    if n < 2:
        return out
    planner = JointPlanner(world, max_step)
    if mode == "fast":
        free = world.motion_free(Q[iu], Q[ju], max_step)
        straight[iu[free], ju[free]] = True
        straight[ju[free], iu[free]] = True
        D[iu[free], ju[free]] = direct[free]
        todo = np.flatnonzero(~free)
        algo = "rrtconnect"
    elif mode == "paper":
        todo = np.arange(len(iu))
        algo = "rrtstar"
    else:
        from cellctl.errors import PlanningError

        raise PlanningError(f"path-cost mode {mode!r} is unknown; expected 'fast' or 'paper'")
    done = len(iu) - len(todo)
    if progress:
        progress(done, len(iu))
    for k in todo:
        i, j = int(iu[k]), int(ju[k])
        ok, length, path = planner.plan(Q[i], Q[j], algo, budget_s, simplify_s, fallback=fallback)
        out.planned += 1
        if ok:
            D[i, j] = length
            out.paths[(i, j)] = path
        else:
            D[i, j] = UNREACHABLE_COST + direct[k]
            out.failed += 1
        done += 1
        if progress:
            progress(done, len(iu))
    out.fallbacks = planner.fallbacks
    D += D.T
    return out


class EdgeCache:
    """Fast mode's lazily evaluated path costs between viewpoint configurations.

    Keys are global node ids (index into the reachable configurations; −1 = start). A pair's
    straight motion is checked once (batched); a colliding pair costs ``LAZY_FACTOR`` × its
    straight distance until :meth:`verify` plans it with RRTConnect. Results survive
    re-selection, so nothing is planned twice.

    Args:
        Q: (n, 6) reachable configurations, rad.
        q_start: (6,) start configuration, rad.
        world: collision world.
        budget_s, simplify_s: RRTConnect and simplification limits per pair, s.
    """

    def __init__(
        self,
        Q: NDArray[np.float64],
        q_start: NDArray[np.float64],
        world: PlanningWorld,
        budget_s: float,
        simplify_s: float,
        max_step: float = 0.02,
    ) -> None:
        self.Q = np.asarray(Q, dtype=np.float64)
        self.q_start = np.asarray(q_start, dtype=np.float64)
        self.world = world
        self.budget_s, self.simplify_s, self.max_step = budget_s, simplify_s, max_step
        self.state: dict[tuple[int, int], tuple[str, float]] = {}  # straight|lazy|planned|failed
        self.paths: dict[tuple[int, int], NDArray[np.float64]] = {}
        self.planner = JointPlanner(world, max_step)
        self.planned = self.failed = self.straight_checked = 0

    def q(self, node: int) -> NDArray[np.float64]:
        return self.q_start if node < 0 else self.Q[node]

    def matrix(self, nodes: list[int]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """Cost matrix over ``nodes`` and the mask of still-estimated (lazy) entries."""
        n = len(nodes)
        iu, ju = np.triu_indices(n, 1)
        keys = [(min(nodes[i], nodes[j]), max(nodes[i], nodes[j])) for i, j in zip(iu, ju, strict=True)]
        unknown = [k for k in keys if k not in self.state]
        if unknown:
            A = np.array([self.q(a) for a, _ in unknown])
            B = np.array([self.q(b) for _, b in unknown])
            free = self.world.motion_free(A, B, self.max_step)
            self.straight_checked += len(unknown)
            for k, f, a, b in zip(unknown, free, A, B, strict=True):
                d = float(np.linalg.norm(b - a))
                self.state[k] = ("straight", d) if f else ("lazy", LAZY_FACTOR * d)
        D = np.zeros((n, n))
        lazy = np.zeros((n, n), dtype=bool)
        for i, j, k in zip(iu, ju, keys, strict=True):
            kind, c = self.state[k]
            D[i, j] = D[j, i] = c
            lazy[i, j] = lazy[j, i] = kind == "lazy"
        return D, lazy

    def verify(self, a: int, b: int) -> bool:
        """Plan pair (a, b) if it is still an estimate; True if it is connected."""
        k = (min(a, b), max(a, b))
        kind, _ = self.state[k]
        if kind == "lazy":
            ok, length, path = self.planner.plan(
                self.q(k[0]), self.q(k[1]), "rrtconnect", self.budget_s, self.simplify_s
            )
            self.planned += 1
            if ok:
                self.state[k] = ("planned", length)
                self.paths[k] = path
            else:
                self.failed += 1
                self.state[k] = ("failed", UNREACHABLE_COST + float(np.linalg.norm(self.q(k[1]) - self.q(k[0]))))
        return self.state[k][0] != "failed"

    def isolated(self, nodes: list[int]) -> list[int]:
        """Nodes not connected to the start by known motions, with ≥ 2 failed links towards it.

        Connected = joined through straight or planned pairs (union-find). A group of
        viewpoints can be mutually reachable yet cut off from the start (e.g. under the bin,
        between its legs); the tour cannot use any of them.
        """
        parent = {n: n for n in nodes}

        def find(x: int) -> int:
            while parent[x] != x:
                parent[x] = parent[parent[x]]
                x = parent[x]
            return x

        for i, a in enumerate(nodes):
            for b in nodes[i + 1 :]:
                kind = self.state.get((min(a, b), max(a, b)), ("?", 0.0))[0]
                if kind in ("straight", "planned"):
                    parent[find(a)] = find(b)
        root = find(-1) if -1 in parent else None
        main = [n for n in nodes if find(n) == root]
        out = []
        for a in nodes:
            if find(a) == root:
                continue
            fails = sum(self.state.get((min(a, b), max(a, b)), ("?", 0.0))[0] == "failed" for b in main)
            group_fails = sum(
                self.state.get((min(x, b), max(x, b)), ("?", 0.0))[0] == "failed"
                for x in nodes
                if find(x) == find(a)
                for b in main
            )
            if fails >= 1 or group_fails >= 2:
                out.append(a)
        return out

    def path(self, a: int, b: int) -> NDArray[np.float64] | None:
        """Planned waypoints a → b (None for straight motions)."""
        p = self.paths.get((min(a, b), max(a, b)))
        if p is None:
            return None
        return p if a < b else p[::-1]
