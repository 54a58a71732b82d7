"""Reachability (paper §IV-A1b), the fast way: analytic IK + batch collision checks.

For every viewpoint direction, distances are tried in preference order and the first one
with a collision-free IK solution within the joint limits is kept. The camera may take any
roll about its optical axis: ``n_roll`` rolls are tried and the viewpoint pose is updated to
the roll actually reached (paper §IV-B1). Among all free solutions the one closest in joint
space to the reference configuration wins, which keeps the later tour short.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cellctl.planning.collision import CollisionWorld
from cellctl.planning.robot import RobotModel
from cellctl.planning.viewpoints import Viewpoints

__all__ = ["Reached", "reachability", "roll_sequence", "wrap_towards"]

_WRAPPABLE = (0, 3, 4, 5)  # joints with a ±2π range: q and q ± 2π are the same geometry


@dataclass
class Reached:
    """Reachable viewpoints (at most one per seed direction).

    Attributes:
        index: (R,) indices into the viewpoints given to :func:`reachability`.
        T: (R, 4, 4) ``T_bin_cam`` at the reached roll.
        q: (R, 6) joint solutions, rad.
        roll: (R,) roll about the optical axis that was reached, rad.
        checks: configurations collision-checked.
        tried: viewpoints whose reachability was evaluated (the others' direction was already
            reached at a preferred distance).
    """

    index: NDArray[np.int64]
    T: NDArray[np.float64]
    q: NDArray[np.float64]
    roll: NDArray[np.float64]
    checks: int
    tried: int


def roll_sequence(n_roll: int) -> NDArray[np.float64]:
    """Rolls 0, +Δ, −Δ, +2Δ, … (rad), Δ = 2π / n_roll: the unrotated pose is preferred."""
    step = 2 * np.pi / max(1, n_roll)
    seq = [0.0]
    k = 1
    while len(seq) < n_roll:
        seq.append(k * step)
        if len(seq) < n_roll:
            seq.append(-k * step)
        k += 1
    return np.array(seq)


def wrap_towards(Q: NDArray[np.float64], q_ref: NDArray[np.float64], robot: RobotModel) -> NDArray[np.float64]:
    """Shift ±2π-range joints by multiples of 2π towards ``q_ref`` while staying within limits."""
    out = np.array(Q, dtype=np.float64, copy=True)
    for j in _WRAPPABLE:
        shifted = out[:, j] + 2 * np.pi * np.round((q_ref[j] - out[:, j]) / (2 * np.pi))
        ok = (shifted >= robot.q_min[j]) & (shifted <= robot.q_max[j])
        out[ok, j] = shifted[ok]
    return out


def _rz(a: float) -> NDArray[np.float64]:
    c, s = np.cos(a), np.sin(a)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    return T


def candidates(
    T_base_bin: NDArray[np.float64],
    T_bin_cam: NDArray[np.float64],
    robot: RobotModel,
    rolls: NDArray[np.float64],
    q_ref: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """IK candidates of one viewpoint over all rolls, sorted by joint distance to ``q_ref``.

    Returns:
        ``(Q (K, 6), roll (K,))``.
    """
    Qs, rs = [], []
    for a in rolls:
        S = robot.ik_cam(T_base_bin @ T_bin_cam @ _rz(a))
        if len(S):
            Qs.append(wrap_towards(S, q_ref, robot))
            rs.append(np.full(len(S), a))
    if not Qs:
        return np.zeros((0, 6)), np.zeros(0)
    Q = np.concatenate(Qs)
    r = np.concatenate(rs)
    order = np.argsort(np.linalg.norm(Q - q_ref, axis=1) + 1e-3 * np.abs(r), kind="stable")
    return Q[order], r[order]


def reachability(
    vp: Viewpoints,
    robot: RobotModel,
    world: CollisionWorld,
    T_base_bin: NDArray[np.float64],
    q_ref: NDArray[np.float64],
    n_roll: int = 12,
    accept: Callable[[int, NDArray[np.float64]], bool] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Reached:
    """Keep, per seed direction, the first distance rank with a free IK solution.

    Args:
        vp: filtered viewpoints (bin frame).
        robot: kinematic model.
        world: collision world for this base pose.
        T_base_bin: (4, 4) bin pose in the base frame.
        q_ref: (6,) reference configuration (home/current), rad.
        n_roll: rolls about the optical axis to try.
        accept: optional extra test ``accept(vp_index, q) -> bool`` on the chosen solution
            (paper mode: "a motion planner finds a path to it").
        progress: ``progress(done, total)`` callback.
    """
    rolls = roll_sequence(n_roll)
    checks0 = world.checks
    resolved: dict[int, tuple[int, NDArray[np.float64], float]] = {}
    tried = 0
    ranks = np.unique(vp.rank)
    total = len(vp)
    done = 0
    for rank in ranks:
        idx = [i for i in np.flatnonzero(vp.rank == rank) if int(vp.seed[i]) not in resolved]
        done += int(np.sum(vp.rank == rank)) - len(idx)
        cand = {}
        for i in idx:
            cand[i] = candidates(T_base_bin, vp.T[i], robot, rolls, q_ref)
        tried += len(idx)
        pending = [i for i in idx if len(cand[i][0])]
        done += len(idx) - len(pending)
        pos = {i: 0 for i in pending}
        chunk = 2
        while pending:
            # check the next `chunk` candidates of every pending viewpoint in one batch
            owners, Qb, rb = [], [], []
            for i in pending:
                Q, r = cand[i]
                sl = slice(pos[i], pos[i] + chunk)
                owners += [i] * len(Q[sl])
                Qb.append(Q[sl])
                rb.append(r[sl])
            free = world.robot_free(np.concatenate(Qb))
            Qcat, rcat = np.concatenate(Qb), np.concatenate(rb)
            owners_a = np.asarray(owners)
            still = []
            for i in pending:
                sel = np.flatnonzero((owners_a == i) & free)
                hit = None
                for s in sel:  # already in preference order
                    if accept is None or accept(i, Qcat[s]):
                        hit = s
                        break
                if hit is not None:
                    resolved[int(vp.seed[i])] = (i, Qcat[hit], float(rcat[hit]))
                    done += 1
                elif accept is not None and len(sel):
                    done += 1  # paper mode: the planner refused the best free goal; no retry
                else:
                    pos[i] += chunk
                    if pos[i] < len(cand[i][0]):
                        still.append(i)
                    else:
                        done += 1
            pending = still
            chunk *= 2
            if progress:
                progress(done, total)
    if progress:
        progress(total, total)
    items = sorted(resolved.values(), key=lambda x: x[0])
    index = np.array([it[0] for it in items], dtype=np.int64)
    q = np.array([it[1] for it in items]).reshape(-1, 6)
    roll = np.array([it[2] for it in items])
    T = np.array([vp.T[i] @ _rz(a) for i, a in zip(index, roll, strict=True)]).reshape(-1, 4, 4)
    return Reached(index=index, T=T, q=q, roll=roll, checks=world.checks - checks0, tried=tried)
