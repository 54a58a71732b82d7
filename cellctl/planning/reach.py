"""Reachability (paper §IV-A1b), the fast way: analytic IK + batch collision checks.

For every viewpoint direction, distances are tried in preference order and the first one
with a collision-free IK solution within the joint limits is kept. The camera may take any
roll about its optical axis: ``n_roll`` rolls are tried and the viewpoint pose is updated to
the roll actually reached (paper §IV-B1). Among all free solutions the one closest in joint
space to the reference configuration wins, which keeps the later tour short.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.catalog import BinMesh
from cellctl.geometry.transforms import invert
from cellctl.planning.collision import PlanningWorld
from cellctl.planning.plan import PlanParams
from cellctl.planning.robot import RobotModel
from cellctl.planning.viewpoints import Viewpoints

__all__ = [
    "Reached",
    "branch_signature",
    "candidates",
    "reachability",
    "robust_acceptor",
    "roll_sequence",
    "wrap_towards",
]

MAX_ACCEPT_TRIES = 8  # solutions per viewpoint offered to ``accept``
SHAPE_SAMPLE = 96  # viewpoints the preferred arm shape is judged on
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
    T = T_base_bin @ T_bin_cam
    for a, S in zip(rolls, robot.ik_cam_many(np.array([T @ _rz(a) for a in rolls])), strict=True):
        if len(S):
            Qs.append(S)
            rs.append(np.full(len(S), a))
    if not Qs:
        return np.zeros((0, 6)), np.zeros(0)
    Q = wrap_towards(np.concatenate(Qs), q_ref, robot)
    r = np.concatenate(rs)
    order = np.argsort(np.linalg.norm(Q - q_ref, axis=1) + 1e-3 * np.abs(r), kind="stable")
    return Q[order], r[order]


def branch_signature(Q: NDArray[np.float64], robot: RobotModel) -> NDArray[np.int64]:
    """IK branch of each configuration as an int 0..7: shoulder (front/back), elbow, wrist flags.

    Straight joint-space motions between configurations of one branch stay "the same arm
    shape" and rarely sweep through the bin; motions across branches flip the arm over.
    """
    F = robot.fk_frames(Q)
    w = F[:, 4, :3, 3]  # wrist-1 centre
    q1 = Q[:, 0]
    front = (w[:, 0] * np.cos(q1) + w[:, 1] * np.sin(q1)) < 0  # DH a2 < 0: the arm reaches along -x1
    elbow = Q[:, 2] > 0
    wrist = np.sin(Q[:, 4]) > 0
    return front.astype(np.int64) * 4 + elbow.astype(np.int64) * 2 + wrist.astype(np.int64)


@dataclass
class _Resolution:
    """What :func:`reachability` has found so far: per seed direction its viewpoint, solution and roll."""

    total: int
    progress: Callable[[int, int], None] | None
    resolved: dict[int, tuple[int, NDArray[np.float64], float]] = field(default_factory=dict)
    tried: int = 0
    done: int = 0
    preferred: int | None = None
    """The preferred arm shape (branch signature), once judged."""
    centre: NDArray[np.float64] | None = None
    """That shape's median configuration."""

    def step(self) -> None:
        """One more viewpoint decided (reported to ``progress``)."""
        self.done += 1
        if self.progress:
            self.progress(self.done, self.total)


def reachability(
    vp: Viewpoints,
    robot: RobotModel,
    world: PlanningWorld,
    T_base_bin: NDArray[np.float64],
    q_ref: NDArray[np.float64],
    n_roll: int = 12,
    accept: Callable[[int, NDArray[np.float64]], bool] | None = None,
    verify: Callable[[int, NDArray[np.float64]], bool] | None = None,
    progress: Callable[[int, int], None] | None = None,
    joinable: Callable[[NDArray[np.float64]], NDArray[np.bool_]] | None = None,
) -> Reached:
    """Keep, per seed direction, the first distance rank with a free IK solution.

    All IK candidates (every roll, every branch) of the viewpoints of one rank are checked in
    one batch. Then one IK branch is preferred for the whole plan — the branch most viewpoints
    can use, judged on a sample of :data:`SHAPE_SAMPLE` viewpoints of the first distance (only
    that arm shape's candidates are then collision-checked) — and each viewpoint takes its
    free candidate of that branch closest to the branch's median configuration (the
    wrist-flipped twin of the branch only when it has none; viewpoints reachable only with
    another arm shape count as unreachable), so consecutive viewpoints are usually joined by
    short, collision-free joint motions.

    Args:
        vp: filtered viewpoints (bin frame).
        robot: kinematic model.
        world: collision world for this base pose.
        T_base_bin: (4, 4) bin pose in the base frame.
        q_ref: (6,) reference configuration (home/current), rad.
        n_roll: rolls about the optical axis to try.
        accept: optional cheap test ``accept(vp_index, q) -> bool``; a refused solution
            passes the turn to the viewpoint's next-best one (up to ``MAX_ACCEPT_TRIES``).
        verify: optional expensive verdict on the first accepted solution (paper mode: a
            motion planner finds a path to it from the start); refused → unreachable.
            (paper mode: "a motion planner finds a path to it from the start").
        progress: ``progress(done, total)`` callback.
        joinable: optional batch test of configurations (e.g. a straight free motion from home
            reaches them): the preferred arm shape is then the most used one some of whose
            solutions near its median pass it (tried in order of use, a few solutions each); the
            most used one when none does. None: the most used one.
    """
    rolls = roll_sequence(n_roll)
    checks0 = world.checks
    st = _Resolution(len(vp), progress)
    for rank in np.unique(vp.rank):
        idx = [int(i) for i in np.flatnonzero(vp.rank == rank) if int(vp.seed[i]) not in st.resolved]
        st.done += int(np.sum(vp.rank == rank)) - len(idx)
        st.tried += len(idx)
        owners, Qs, rs = [], [], []
        for i in idx:
            Q, r = candidates(T_base_bin, vp.T[i], robot, rolls, q_ref)
            owners += [i] * len(Q)
            Qs.append(Q)
            rs.append(r)
        if not owners:
            continue
        Qc, rc, own = np.concatenate(Qs), np.concatenate(rs), np.asarray(owners)
        br = branch_signature(Qc, robot)
        if st.preferred is None:
            # the arm shape most viewpoints can use, judged on every k-th viewpoint (≤ SHAPE_SAMPLE):
            # then only that shape's solutions need the collision check (3/4 of them are not)
            ids = np.unique(own)
            m = np.isin(own, ids[:: max(1, len(ids) // SHAPE_SAMPLE)])
            fs = world.robot_free(Qc[m])
            if fs.any():
                st.preferred, st.centre = _preferred_shape(own[m][fs], br[m][fs], Qc[m][fs], q_ref, joinable)
        if st.preferred is not None and st.centre is not None:
            _resolve_in_shape(st, vp, idx, Qc, rc, own, br, world, accept, verify)
        else:
            _resolve_any_shape(st, vp, idx, Qc, rc, own, br, world, q_ref, accept, verify, joinable)
    if progress:
        progress(st.total, st.total)
    items = sorted(st.resolved.values(), key=lambda x: x[0])
    index = np.array([it[0] for it in items], dtype=np.int64)
    q = np.array([it[1] for it in items]).reshape(-1, 6)
    roll = np.array([it[2] for it in items])
    T = np.array([vp.T[i] @ _rz(a) for i, a in zip(index, roll, strict=True)]).reshape(-1, 4, 4)
    return Reached(index=index, T=T, q=q, roll=roll, checks=world.checks - checks0, tried=st.tried)


def _resolve_in_shape(
    st: _Resolution,
    vp: Viewpoints,
    idx: list[int],
    Qc: NDArray[np.float64],
    rc: NDArray[np.float64],
    own: NDArray[np.int64],
    br: NDArray[np.int64],
    world: PlanningWorld,
    accept: Callable[[int, NDArray[np.float64]], bool] | None,
    verify: Callable[[int, NDArray[np.float64]], bool] | None,
) -> None:
    """One rank once the arm shape is fixed: only its solutions can be kept, so only those are checked."""
    assert st.preferred is not None and st.centre is not None
    shape = (br >> 1) == (st.preferred >> 1)
    Qc, rc, own, br = Qc[shape], rc[shape], own[shape], br[shape]
    for i, k in _lazy_first(Qc, rc, own, br, idx, st.preferred, st.centre, world, accept).items():
        Qi, ri = k
        if verify is None or verify(i, Qi):
            st.resolved[int(vp.seed[i])] = (i, Qi, float(ri))
    st.done += len(idx)
    if st.progress:
        st.progress(st.done, st.total)


def _resolve_any_shape(
    st: _Resolution,
    vp: Viewpoints,
    idx: list[int],
    Qc: NDArray[np.float64],
    rc: NDArray[np.float64],
    own: NDArray[np.int64],
    br: NDArray[np.int64],
    world: PlanningWorld,
    q_ref: NDArray[np.float64],
    accept: Callable[[int, NDArray[np.float64]], bool] | None,
    verify: Callable[[int, NDArray[np.float64]], bool] | None,
    joinable: Callable[[NDArray[np.float64]], NDArray[np.bool_]] | None,
) -> None:
    """One rank before the arm shape is fixed: every candidate checked, the shape judged on the free ones."""
    free = world.robot_free(Qc)
    Qc, rc, own, br = Qc[free], rc[free], own[free], br[free]
    if st.preferred is None and len(Qc):
        st.preferred, st.centre = _preferred_shape(own, br, Qc, q_ref, joinable)
    offers: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
    for i in idx:
        m = own == i
        if not m.any():
            st.done += 1
            continue
        Qi, ri, bi = Qc[m], rc[m], br[m]
        # only the preferred arm shape (shoulder + elbow); a wrist flip is allowed at a
        # penalty. Other shapes need the arm to swing through singular/crowded regions,
        # which is rarely possible next to the bin (measured: most such motions fail).
        same = (bi >> 1) == (st.preferred >> 1)
        if not same.any():
            st.done += 1
            continue
        Qi, ri, bi = Qi[same], ri[same], bi[same]
        key = np.linalg.norm(Qi - st.centre, axis=1) + 100.0 * (bi != st.preferred)
        s = np.argsort(key, kind="stable")[:MAX_ACCEPT_TRIES]
        offers[i] = (Qi[s], ri[s])
    first = _first_accepted(offers, accept)
    for i, (Qi, ri) in offers.items():
        k = first.get(i)
        # paper mode: the planner's verdict on the first acceptable goal decides
        if k is not None and (verify is None or verify(i, Qi[k])):
            st.resolved[int(vp.seed[i])] = (i, Qi[k], float(ri[k]))
        st.step()


JOIN_TRIES = 4  # solutions nearest a shape's median that ``joinable`` is asked about


def _preferred_shape(
    own: NDArray[np.int64],
    br: NDArray[np.int64],
    Q: NDArray[np.float64],
    q_ref: NDArray[np.float64],
    joinable: Callable[[NDArray[np.float64]], NDArray[np.bool_]] | None,
) -> tuple[int, NDArray[np.float64]]:
    """The IK branch most viewpoints can use (free solutions ``Q`` of viewpoints ``own``, branches ``br``)
    and its median configuration; with ``joinable``, the most used one whose solutions nearest its median
    pass it (the most used one when none does)."""
    per_branch = [len(np.unique(own[br == b])) for b in range(8)]
    preferred = int(np.argmax(per_branch))
    if joinable is not None:
        for b in np.argsort([-n for n in per_branch], kind="stable"):
            if per_branch[b] == 0:
                break
            Qb = Q[br == b]
            near = Qb[np.argsort(np.linalg.norm(Qb - np.median(Qb, axis=0), axis=1), kind="stable")[:JOIN_TRIES]]
            if joinable(near).any():
                preferred = int(b)
                break
    sel = br == preferred
    return preferred, (np.median(Q[sel], axis=0) if sel.any() else q_ref)


def _lazy_first(
    Qc: NDArray[np.float64],
    rc: NDArray[np.float64],
    own: NDArray[np.int64],
    br: NDArray[np.int64],
    idx: list[int],
    preferred: int,
    centre: NDArray[np.float64],
    world: PlanningWorld,
    accept: Callable[[int, NDArray[np.float64]], bool] | None,
) -> dict[int, tuple[NDArray[np.float64], float]]:
    """Per viewpoint, its first free solution (in preference order) that ``accept`` takes.

    The answer of checking every candidate for collisions and offering the first
    :data:`MAX_ACCEPT_TRIES` free ones in order, but the collision checks go in rounds over
    the next few candidates of each viewpoint still open: most viewpoints' preferred solution
    is free and accepted, so most of the other candidates are never checked.
    """
    order: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
    for i in idx:
        m = own == i
        if not m.any():
            continue
        Qi, ri, bi = Qc[m], rc[m], br[m]
        key = np.linalg.norm(Qi - centre, axis=1) + 100.0 * (bi != preferred)
        s = np.argsort(key, kind="stable")
        order[i] = (Qi[s], ri[s])
    pos = dict.fromkeys(order, 0)
    offered = dict.fromkeys(order, 0)
    out: dict[int, tuple[NDArray[np.float64], float]] = {}
    batch = 2
    while pos:
        ids = list(pos)
        parts = [order[i][0][pos[i] : pos[i] + batch] for i in ids]
        free = world.robot_free(np.concatenate(parts))
        offers: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
        at = 0
        for i, part in zip(ids, parts, strict=True):
            f = free[at : at + len(part)]
            at += len(part)
            sl = np.flatnonzero(f)[: MAX_ACCEPT_TRIES - offered[i]] + pos[i]
            offers[i] = (order[i][0][sl], order[i][1][sl])
            offered[i] += len(sl)
            pos[i] += len(part)
        first = _first_accepted(offers, accept)
        for i in ids:
            k = first.get(i)
            if k is not None:
                out[i] = (offers[i][0][k], float(offers[i][1][k]))
            if k is not None or offered[i] >= MAX_ACCEPT_TRIES or pos[i] >= len(order[i][0]):
                del pos[i]
        batch *= 2
    return out


def _first_accepted(
    offers: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]],
    accept: Callable[[int, NDArray[np.float64]], bool] | None,
) -> dict[int, int]:
    """Per viewpoint, the position of its first offered solution ``accept`` takes (absent: none).

    An acceptor with a batch form (``accept.many(Q)``) is asked for every viewpoint's k-th
    offer at once, k = 0, 1, …: the same answer as asking one by one in order, at a fraction
    of the per-call cost (the parking-robustness test checks six moved worlds per solution).
    """
    if accept is None:
        return {i: 0 for i, (Q, _r) in offers.items() if len(Q)}
    many = getattr(accept, "many", None)
    out: dict[int, int] = {}
    if many is None:
        for i, (Q, _r) in offers.items():
            k = next((k for k in range(len(Q)) if accept(i, Q[k])), None)
            if k is not None:
                out[i] = k
        return out
    for k in range(MAX_ACCEPT_TRIES):
        ask = [i for i, (Q, _r) in offers.items() if i not in out and len(Q) > k]
        if not ask:
            break
        ok = many(np.array([offers[i][0][k] for i in ask]))
        out.update({i: k for i, good in zip(ask, ok, strict=True) if good})
    return out


class _RobustAcceptor:
    """Parking robustness of configurations (see :func:`robust_acceptor`), one or many at a time."""

    def __init__(
        self,
        robot: RobotModel,
        worlds: list[PlanningWorld],
        inv_errors: list[NDArray[np.float64]],
    ) -> None:
        self.robot, self.worlds, self.inv_errors = robot, worlds, inv_errors

    def __call__(self, _i: int, q: NDArray[np.float64]) -> bool:
        return bool(self.many(q[None])[0])

    def many(self, Q: NDArray[np.float64]) -> NDArray[np.bool_]:
        """(N,) True where configuration ``Q[n]`` survives every parking error."""
        Q = np.atleast_2d(Q)
        T_base_cam = self.robot.fk_cam(Q)
        ok = np.ones(len(Q), dtype=bool)
        for Ei, w in zip(self.inv_errors, self.worlds, strict=True):
            best = np.zeros_like(Q)
            live = np.flatnonzero(ok)
            sols = self.robot.ik_cam_many(Ei @ T_base_cam[live]) if len(live) else []
            for n, S in zip(live, sols, strict=True):
                if len(S) == 0:
                    ok[n] = False
                    continue
                S = wrap_towards(S, Q[n], self.robot)
                b = S[np.argmin(np.abs(S - Q[n]).max(axis=1))]
                if np.abs(b - Q[n]).max() > 0.5:
                    ok[n] = False
                    continue
                best[n] = b
            idx = np.flatnonzero(ok)
            if len(idx):
                ok[idx] = w.robot_free(best[idx])
        return ok


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
    worlds = [PlanningWorld(mesh, robot, T_bin_base @ E, margin=params.margin) for E in errors]
    inv_errors = [invert(E) for E in errors]

    return _RobustAcceptor(robot, worlds, inv_errors)
