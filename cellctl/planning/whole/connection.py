"""Connection: a station's reachable viewpoints joined to home by straight, collision-free motions.

Connected = the station's start configuration (the arm's home, the "candle" the base drives
with) reaches the viewpoint's configuration by a straight joint motion that is collision-free
at the sim arm's own check step, directly or along a chain of such motions through other
viewpoints (:func:`connect`, :func:`chain_to_start`). :func:`wrap_window` puts a station's
configurations into one 2π window per ±2π joint.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cellctl.planning.collision import PlanningWorld
from cellctl.planning.reach import Reached
from cellctl.planning.robot import RobotModel
from cellctl.planning.viewpoints import Viewpoints

__all__ = ["CHAIN_ROUNDS", "COARSE_STEP_RAD", "Connected", "chain_to_start", "connect", "wrap_window"]


@dataclass
class Connected:
    """Reachable viewpoints after connection, and what it did.

    Attributes:
        reached: the connected viewpoints (a subset of the reachable ones, some replaced).
        parent: (R,) per viewpoint the node its straight motion comes from: -1 = the start,
            k ≥ 0 = viewpoint k (a chain of straight motions back to the start).
        replaced: viewpoints whose first solution was not connected and another one was.
        unconnected: directions with no connected solution (left out before selection).
    """

    reached: Reached
    parent: NDArray[np.int64]
    replaced: int
    unconnected: int


COARSE_STEP_RAD = 0.02  # the pairwise matrix's check step (the single-station planner's)
CHAIN_ROUNDS = 3  # straight-motion hops a viewpoint may be away from the start
NEAREST = 3  # connected nodes a viewpoint tries to join (nearest in joint space)


def _join(
    world: PlanningWorld,
    Q: NDArray[np.float64],
    nodes: NDArray[np.float64],
    node_ids: NDArray[np.int64],
    max_step: float,
) -> NDArray[np.int64]:
    """Per row of ``Q``: the id of a node it reaches by a straight free motion (nearest first), or -2."""
    if len(Q) == 0 or len(nodes) == 0:
        return np.full(len(Q), -2, dtype=np.int64)
    d = np.linalg.norm(Q[:, None, :] - nodes[None, :, :], axis=2)
    k = min(NEAREST, len(nodes))
    near = np.argsort(d, axis=1)[:, :k]
    out = np.full(len(Q), -2, dtype=np.int64)
    # nearest first, the next one only for rows whose nearer ones collide: the same answer as
    # checking all k at once, with about 1/k of the checks (most rows join their nearest)
    for r in range(k):
        todo = np.flatnonzero(out == -2)
        if len(todo) == 0:
            break
        ok = world.motion_free(Q[todo], nodes[near[todo, r]], max_step)
        out[todo[ok]] = node_ids[near[todo[ok], r]]
    return out


def connect(
    vp: Viewpoints,
    reached: Reached,
    robot: RobotModel,
    world: PlanningWorld,
    T_base_bin: NDArray[np.float64],
    q_start: NDArray[np.float64],
    n_roll: int,
    accept: Callable[[int, NDArray[np.float64]], bool] | None,
    max_step: float,
    wrap: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
) -> Connected:
    """Keep only viewpoints joined to the start by straight, collision-free joint motions.

    Each viewpoint joins the start directly or one of the already joined viewpoints nearest to
    it (≤ :data:`CHAIN_ROUNDS` hops). One that joins nothing is replaced — before selection —
    by its next-best solution (other rolls and IK solutions of the plan's arm shape, at its own
    distance, then the next) that joins; a direction none of whose solutions joins is left out.
    ``wrap`` (:func:`wrap_window`) puts the replacements' ±2π joints in the reached ones' window.
    """
    from cellctl.planning.reach import _rz, branch_signature, candidates, roll_sequence

    n = len(reached.index)
    if n == 0:
        return Connected(reached, np.zeros(0, np.int64), 0, 0)
    T, q, roll, index = reached.T.copy(), reached.q.copy(), reached.roll.copy(), reached.index.copy()
    parent = np.full(n, -2, dtype=np.int64)
    parent[world.motion_free(np.repeat(q_start[None], n, axis=0), q, max_step)] = -1

    def grow() -> None:
        for _ in range(CHAIN_ROUNDS):
            todo = np.flatnonzero(parent == -2)
            done = np.flatnonzero(parent != -2)
            if len(todo) == 0 or len(done) == 0:
                return
            got = _join(world, q[todo], q[done], done, max_step)
            if not (got >= 0).any():
                return
            parent[todo[got >= 0]] = got[got >= 0]

    grow()
    replaced = 0
    todo = np.flatnonzero(parent == -2)
    if len(todo):
        joined = np.flatnonzero(parent != -2)
        shape = int(np.bincount(branch_signature(q[joined], robot) >> 1).argmax()) if len(joined) else None
        rolls = roll_sequence(n_roll)
        owners, Qs, rs, vidx = [], [], [], []
        for k in todo:
            i0 = int(reached.index[k])
            same_seed = np.flatnonzero(vp.seed == vp.seed[i0])
            for i in sorted(same_seed, key=lambda i: (int(vp.rank[i]) != int(vp.rank[i0]), int(vp.rank[i]))):
                Qc, rc = candidates(T_base_bin, vp.T[i], robot, rolls, q_start)
                owners += [k] * len(Qc)
                Qs.append(Qc)
                rs.append(rc)
                vidx += [i] * len(Qc)
        if owners:
            Qc, rc = np.concatenate(Qs), np.concatenate(rs)
            if wrap is not None:
                Qc = wrap(Qc)
            own, vi = np.asarray(owners), np.asarray(vidx)
            if shape is not None:  # only the plan's arm shape: check only those solutions
                same = (branch_signature(Qc, robot) >> 1) == shape
                Qc, rc, own, vi = Qc[same], rc[same], own[same], vi[same]
            free = world.robot_free(Qc)
            Qc, rc, own, vi = Qc[free], rc[free], own[free], vi[free]
            # at most 6 solutions per direction, in preference order (the candidates' order)
            keep = np.zeros(len(own), dtype=bool)
            for k in np.unique(own):
                keep[np.flatnonzero(own == k)[:6]] = True
            Qc, rc, own, vi = Qc[keep], rc[keep], own[keep], vi[keep]
            nodes_ids = np.r_[-1, joined].astype(np.int64)
            nodes_q = np.vstack([q_start[None], q[joined]])
            # in preference order, one solution per direction and round: a direction's next
            # solution is checked only while its earlier ones fail (same answer, fewer checks)
            rank_in = np.zeros(len(own), dtype=np.int64)
            for k in np.unique(own):
                m = np.flatnonzero(own == k)
                rank_in[m] = np.arange(len(m))
            open_ = set(np.unique(own).tolist())
            for r in range(int(rank_in.max()) + 1 if len(own) else 0):
                ms = np.flatnonzero((rank_in == r) & np.isin(own, list(open_)))
                if len(ms) == 0:
                    break
                got = _join(world, Qc[ms], nodes_q, nodes_ids, max_step)
                for mi, g in zip(ms, got, strict=True):
                    if g == -2 or (accept is not None and not accept(int(vi[mi]), Qc[mi])):
                        continue
                    ki = int(own[mi])
                    T[ki], q[ki], roll[ki], index[ki] = vp.T[vi[mi]] @ _rz(float(rc[mi])), Qc[mi], rc[mi], vi[mi]
                    parent[ki] = g
                    replaced += 1
                    open_.discard(ki)
        grow()
    sel = np.flatnonzero(parent != -2)
    remap = np.full(n, -1, dtype=np.int64)
    remap[sel] = np.arange(len(sel))
    par = np.where(parent[sel] >= 0, remap[np.maximum(parent[sel], 0)], -1)
    out = Reached(index=index[sel], T=T[sel], q=q[sel], roll=roll[sel], checks=reached.checks, tried=reached.tried)
    return Connected(out, par.astype(np.int64), replaced, int(n - len(sel)))


def chain_to_start(k: int, parent: NDArray[np.int64], Q: NDArray[np.float64]) -> list[NDArray[np.float64]]:
    """Configurations from viewpoint ``k`` back along its chain of straight motions (start excluded)."""
    out = []
    while k >= 0:
        out.append(Q[k])
        k = int(parent[k])
    return out


def wrap_window(
    Q: NDArray[np.float64], robot: RobotModel, q_ref: NDArray[np.float64]
) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
    """A map of configurations into one 2π window per ±2π joint, cut where ``Q`` leaves its widest gap.

    q and q ± 2π of a ±2π joint are the same arm, but a straight move between them turns the
    joint a full circle. IK solutions are wrapped towards home (``q_ref``), whose base joint
    faces away from the bin: a station's viewpoints straddle the cut at home ± π, and
    neighbours 0.3 rad apart got 6.0 rad base turns (case study seed 2: 50 s of its 132 s of
    tour motion were base-joint-bound moves). Per joint, the angles of ``Q`` are cut at their
    largest circular gap (so the set is one contiguous arc) and the arc is shifted by 2πk to lie
    within the joint's limits, its middle nearest ``q_ref``. Other joints are unchanged.
    """
    from cellctl.planning.reach import _WRAPPABLE

    two_pi = 2.0 * np.pi
    lo = np.full(6, -np.inf)
    for j in _WRAPPABLE:
        if len(Q) == 0:
            break
        a = np.sort(np.mod(Q[:, j], two_pi))
        gaps = np.diff(np.r_[a, a[0] + two_pi])
        g = int(np.argmax(gaps))
        start = a[(g + 1) % len(a)]  # the arc begins after its widest gap
        width = float(two_pi - gaps[g])
        ks = np.arange(-3, 4)
        mids = start + ks * two_pi + width / 2.0
        fits = (start + ks * two_pi >= robot.q_min[j] - 1e-9) & (start + ks * two_pi + width <= robot.q_max[j] + 1e-9)
        if not fits.any():
            continue
        k = ks[fits][int(np.argmin(np.abs(mids[fits] - q_ref[j])))]
        lo[j] = start + k * two_pi - 1e-9

    def into(X: NDArray[np.float64]) -> NDArray[np.float64]:
        out = np.array(X, dtype=np.float64, copy=True)
        for j in _WRAPPABLE:
            if np.isfinite(lo[j]):
                w = lo[j] + np.mod(out[..., j] - lo[j], two_pi)
                ok = (w >= robot.q_min[j] - 1e-9) & (w <= robot.q_max[j] + 1e-9)
                out[..., j] = np.where(ok, w, out[..., j])
        return out

    return into
