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

from cellctl.planning.collision import CollisionWorld

__all__ = ["JointPlanner", "PathCosts", "path_cost_matrix", "verify_edge"]

UNREACHABLE_COST = 1.0e3  # rad; a pair no planner connected is avoided by the tour, not fatal


class JointPlanner:
    """OMPL 2.x (nanobind) joint-space planner on a :class:`CollisionWorld`.

    Motion validity uses the world's batched straight-line check (a custom
    ``MotionValidator``), so one OMPL edge costs one vectorised call, not dozens.

    Args:
        world: collision world.
        max_step: joint-space interpolation step for edge checks, rad.
    """

    def __init__(self, world: CollisionWorld, max_step: float = 0.02) -> None:
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

    def _setup(self):  # noqa: ANN202 - ompl SimpleSetup
        from ompl import base as ob
        from ompl import geometric as og

        world, step = self.world, self.max_step
        ss = og.SimpleSetup(self.space)
        si = ss.getSpaceInformation()

        def valid(s) -> bool:  # noqa: ANN001 - OMPL state
            return bool(world.robot_free(np.array([s[i] for i in range(6)]))[0])

        class _Motion(ob.MotionValidator):
            def checkMotion(self, s1, s2, *args) -> bool:  # noqa: ANN001, ANN002, N802 - OMPL API
                a = np.array([s1[i] for i in range(6)])
                b = np.array([s2[i] for i in range(6)])
                return bool(world.motion_free(a, b, step)[0])

        ss.setStateValidityChecker(valid)
        mv = _Motion(si)
        si.setMotionValidator(mv)
        return ss, si, mv

    def plan(
        self, q_a: NDArray[np.float64], q_b: NDArray[np.float64], planner: str, budget_s: float, simplify_s: float
    ) -> tuple[bool, float, NDArray[np.float64]]:
        """Plan ``q_a → q_b``.

        Args:
            planner: "rrtconnect" (stops at the first solution) or "rrtstar" (anytime: uses
                the whole budget, as in the paper).
            budget_s: planning time limit, s.
            simplify_s: time limit of the path simplification, s (0: none).

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
            ss.setPlanner(og.RRTstar(si))
        else:
            ss.setPlanner(og.RRTConnect(si))
        ss.solve(float(budget_s))
        if not ss.haveExactSolutionPath():
            ss.clear()
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
    paths: dict[tuple[int, int], NDArray[np.float64]] = field(default_factory=dict)
    lazy: NDArray[np.bool_] | None = None


LAZY_FACTOR = 1.5  # estimated detour of a colliding pair relative to the straight joint distance


def verify_edge(
    pc: PathCosts, Q: NDArray[np.float64], i: int, j: int, planner: JointPlanner, budget_s: float, simplify_s: float
) -> bool:
    """Plan a lazily estimated pair now (RRTConnect); update ``pc`` in place.

    Returns:
        True if a path was found (its length replaces the estimate).
    """
    a, b = min(i, j), max(i, j)
    if pc.lazy is None or not pc.lazy[a, b]:
        return pc.D[a, b] < UNREACHABLE_COST
    ok, length, path = planner.plan(Q[a], Q[b], "rrtconnect", budget_s, simplify_s)
    pc.planned += 1
    pc.lazy[a, b] = pc.lazy[b, a] = False
    if ok:
        pc.D[a, b] = pc.D[b, a] = length
        pc.paths[(a, b)] = path
    else:
        pc.D[a, b] = pc.D[b, a] = UNREACHABLE_COST + float(np.linalg.norm(Q[b] - Q[a]))
        pc.failed += 1
    return ok


def path_cost_matrix(
    Q: NDArray[np.float64],
    world: CollisionWorld,
    mode: str = "fast",
    *,
    budget_s: float = 1.0,
    simplify_s: float = 0.2,
    max_step: float = 0.02,
    lazy: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> PathCosts:
    """Pairwise path costs between configurations ``Q`` (n, 6).

    Args:
        mode: "fast" (straight line, RRTConnect where it collides) or "paper" (RRT* with
            ``budget_s`` for every pair).
        budget_s: planner time limit per query, s.
        simplify_s: simplification time limit per planned path, s.
        lazy: fast mode only: do not plan colliding pairs now; give them the estimate
            ``LAZY_FACTOR`` × straight distance and mark them in ``PathCosts.lazy``.
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
        if lazy:
            # lazy evaluation: colliding pairs get an optimistic estimate now; only the pairs
            # the tour actually uses are planned later (see :func:`verify_edge`)
            D[iu[todo], ju[todo]] = LAZY_FACTOR * direct[todo]
            out.lazy = np.zeros((n, n), dtype=bool)
            out.lazy[iu[todo], ju[todo]] = True
            out.lazy[ju[todo], iu[todo]] = True
            todo = todo[:0]
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
        ok, length, path = planner.plan(Q[i], Q[j], algo, budget_s, simplify_s)
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
    D += D.T
    return out


