"""Timed tours of one station's share and the refinements of a tour (motion time, not joint distance).

:func:`_timed_tour` orders a station's viewpoints by modelled motion time (ant colony + 2-opt,
every move straight or via home along the chains, re-checked at the sim arm's step);
:func:`_take_detours` / :func:`_detour` replace moves via home by shorter free ways round;
:func:`_refine_configurations` picks each viewpoint's IK solution nearest its tour neighbours;
:func:`_shift_tour` turns a whole tour by 2π where its ends get faster.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from cellctl.planning.collision import PlanningWorld
from cellctl.planning.robot import RobotModel
from cellctl.planning.whole.connection import Connected, chain_to_start
from cellctl.planning.whole.records import TimingModel

__all__ = [
    "ALTERNATIVES",
    "DETOUR_GROUPS",
    "DETOUR_PULLS",
    "END_PENALTY_S",
    "NO_MOVE_S",
    "SHIFT_TRIES",
]
END_PENALTY_S = 100.0  # makes the tour's home node its last (an interior visit pays it twice)
NO_MOVE_S = 1.0e4  # a move the sim arm could not make: straight collides and no way via home


@dataclass
class _TourGraph:
    """The motion-time graph of one tour: ``[start, *viewpoints]`` plus node ``n``, home at the tour's end.

    Filled by :func:`_tour_graph`; the fine-step checks then update it in place (a move found to
    collide goes via home, a node without a free way home is no end and no via-home end).
    """

    nodes: NDArray[np.float64]
    """(n, 6): the start, then the viewpoints' configurations."""
    hubs: list[NDArray[np.float64]]
    """Each node's known way home (straight motions, ``[q, …, home]``)."""
    home_t: NDArray[np.float64]
    direct: NDArray[np.bool_]
    """One straight motion home, free at the sim arm's step (optimistic until :attr:`known`)."""
    known: NDArray[np.bool_]
    Tm: NDArray[np.float64]
    """(n + 1, n + 1) motion seconds; :data:`NO_MOVE_S` where the sim arm cannot move."""
    straight: NDArray[np.bool_]
    n_straight: int
    """Straight pairs of the matrix (checked at ``max_step``)."""
    checked: set[tuple[int, int]] = field(default_factory=set)
    """Straight moves checked at ``fine_step``."""

    @property
    def n(self) -> int:
        return len(self.nodes)


def _timed_tour(
    q_start: NDArray[np.float64],
    start_hub: list[NDArray[np.float64]],
    sel: NDArray[np.int64],
    con: Connected,
    q_home: NDArray[np.float64],
    world: PlanningWorld,
    timing: TimingModel,
    rng: np.random.Generator,
    max_step: float,
    fine_step: float,
    tuck: bool = True,
    q_sel: NDArray[np.float64] | None = None,
    init: NDArray[np.int64] | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.float64], list[NDArray[np.float64]], list[float], int, int, NDArray[np.int64]]:
    """Order ``[start, *Q[sel]]`` by motion time; every move straight or via home along the chains.

    ``tuck``: the arm goes home after this tour (False: another surface's tour follows from its
    end, so a last viewpoint without a free straight way home is no move the arm must make).
    ``q_sel``: the viewpoints' configurations (len(sel), 6) instead of ``Q[sel]`` (a refined
    tour's); one that differs from ``Q[sel]`` goes home straight only (its chain starts elsewhere).
    ``init``: a node order to start 2-opt from instead of the ant colony's (a second order).

    Ant colony + 2-opt on the motion-time matrix (pairs checked at ``max_step``; a colliding
    pair costs its way via home: both ends' chains of straight motions, known free). The moves
    the tour uses are checked again at ``fine_step`` (the sim arm's step); one that fails there
    goes via home too, and 2-opt repairs the order (≤ 4 rounds).

    ``start_hub`` is the start's known way home (straight motions, ``[q_start, …, home]``).

    Returns:
        ``(order, D_rad, edge paths along the order (K_i, 6) incl. ends, edge seconds along
        the order, straight pairs of the matrix, segments of the ways via home that collide at
        ``fine_step``, the ids in ``sel`` of the viewpoints without a way home at ``fine_step``
        that those segments or the tour's end use)``.
    """
    from cellctl.planning.tour import ant_colony, two_opt

    g = _tour_graph(q_start, start_hub, sel, con, q_home, world, timing, max_step, q_sel)
    n = g.n
    first = ant_colony(g.Tm, rng) if init is None else np.r_[np.asarray(init, dtype=np.int64), n]
    full = np.asarray(two_opt(g.Tm, first), dtype=np.int64)
    order, ends_home = _fine_checked_order(g, full[full != n], int(full[-1]) == n, q_home, world, fine_step)
    paths, secs, Dr = _tour_paths(g, order, timing)
    detoured = _take_detours(order, g.nodes, paths, secs, Dr, g.direct, q_home, world, timing, fine_step)
    direct = g.direct
    # moves the sim arm could not make: via home from/to a node that is not direct, and the end
    bad = [
        (a, b)
        for p, a, b, dt in zip(paths, order[:-1], order[1:], detoured, strict=True)
        if len(p) > 2 and not dt and not (direct[a] and direct[b])
    ]
    unverified = len(bad)
    last = int(order[-1])
    unverified += 0 if (ends_home and direct[last]) or not tuck else 1
    # the viewpoints whose missing way home makes those moves: their chains are what a retry adds
    stuck = {x for e in bad for x in e if not direct[x]} | ({last} if tuck and not direct[last] else set())
    stuck_ids = np.array(sorted(int(sel[x - 1]) for x in stuck if x > 0), dtype=np.int64)
    return order, Dr, paths, secs, g.n_straight, int(unverified), stuck_ids


def _tour_graph(
    q_start: NDArray[np.float64],
    start_hub: list[NDArray[np.float64]],
    sel: NDArray[np.int64],
    con: Connected,
    q_home: NDArray[np.float64],
    world: PlanningWorld,
    timing: TimingModel,
    max_step: float,
    q_sel: NDArray[np.float64] | None,
) -> _TourGraph:
    """The motion-time matrix of ``[start, *viewpoints]`` and home, pairs checked at ``max_step``."""
    Qall = con.reached.q
    Qs = Qall[sel] if q_sel is None else q_sel
    nodes = np.vstack([q_start[None], Qs])
    n = len(nodes)
    hubs = [np.array(start_hub)] + [
        np.array([*chain_to_start(int(k), con.parent, Qall), q_home])
        if np.array_equal(q, Qall[k])
        else np.array([q, q_home])
        for k, q in zip(sel, Qs, strict=True)
    ]
    home_t = np.array([timing.motion_s(h) for h in hubs])
    # "direct": one straight motion home, free at the sim arm's step. Only between direct nodes may
    # a move go via home: that is the sim arm's own fallback (plan_path(a, home), plan_path(home, b)),
    # which finds a straight motion there and no chain through other viewpoints
    # Checked lazily, only where the tour uses it (a move via home, the end): a fine-step check of
    # a motion home costs ~600 configurations, and most nodes are joined straight.
    two = np.array([len(h) == 2 for h in hubs])
    direct = two.copy()  # optimistic until checked
    known = ~two
    iu, ju = np.triu_indices(n, 1)
    free = world.motion_free(nodes[iu], nodes[ju], max_step) if len(iu) else np.zeros(0, dtype=bool)
    # node n = home at the end of the tour (the arm tucks before the base drives): reached from a
    # direct node only, with a penalty that an interior visit pays twice, so it ends the tour
    Tm = np.zeros((n + 1, n + 1))
    Tm[:n, n] = Tm[n, :n] = np.where(direct, home_t + END_PENALTY_S, NO_MOVE_S)
    straight = np.zeros((n + 1, n + 1), dtype=bool)
    for k, (i, j) in enumerate(zip(iu, ju, strict=True)):
        if free[k]:
            Tm[i, j] = Tm[j, i] = timing.motion_s(np.array([nodes[i], nodes[j]]))
            straight[i, j] = straight[j, i] = True
        else:
            Tm[i, j] = Tm[j, i] = float(home_t[i] + home_t[j]) if direct[i] and direct[j] else NO_MOVE_S
    return _TourGraph(nodes, hubs, home_t, direct, known, Tm, straight, int(free.sum()))


def _check_direct(
    g: _TourGraph, order: NDArray[np.int64], q_home: NDArray[np.float64], world: PlanningWorld, fine_step: float
) -> bool:
    """Check the tour's end and its moves' via-home ends; True when one is not direct."""
    n, straight, Tm = g.n, g.straight, g.Tm
    need = {int(order[-1])} | {
        int(x) for a, b in zip(order[:-1], order[1:], strict=True) if not straight[a, b] for x in (a, b)
    }
    todo = [k for k in sorted(need) if not g.known[k]]
    if not todo:
        return False
    ok = world.motion_free(g.nodes[todo], np.repeat(q_home[None], len(todo), axis=0), fine_step)
    for k, good in zip(todo, ok, strict=True):
        g.known[k], g.direct[k] = True, bool(good)
        if not good:  # no way home at the sim arm's step: no move via home, not the end
            Tm[k, n] = Tm[n, k] = NO_MOVE_S
            other = ~straight[k, :n]
            other[k] = False
            Tm[k, :n][other] = NO_MOVE_S
            Tm[:n, k][other] = NO_MOVE_S
    return not ok.all()


def _fine_checked_order(
    g: _TourGraph,
    order: NDArray[np.int64],
    ends_home: bool,
    q_home: NDArray[np.float64],
    world: PlanningWorld,
    fine_step: float,
) -> tuple[NDArray[np.int64], bool]:
    """Check the order's moves at ``fine_step``; 2-opt repairs it after a failure (≤ 6 rounds)."""
    from cellctl.planning.tour import two_opt

    n, straight, Tm, direct, home_t, nodes = g.n, g.straight, g.Tm, g.direct, g.home_t, g.nodes
    for _round in range(6):
        edges = [
            (int(a), int(b))
            for a, b in zip(order[:-1], order[1:], strict=True)
            if straight[a, b] and (min(a, b), max(a, b)) not in g.checked
        ]
        changed = False
        if edges:
            ok = world.motion_free(
                np.array([nodes[a] for a, _ in edges]), np.array([nodes[b] for _, b in edges]), fine_step
            )
            for (a, b), good in zip(edges, ok, strict=True):
                g.checked.add((min(a, b), max(a, b)))
                if not good:
                    straight[a, b] = straight[b, a] = False
                    Tm[a, b] = Tm[b, a] = float(home_t[a] + home_t[b]) if direct[a] and direct[b] else NO_MOVE_S
            changed = not ok.all()
        changed = _check_direct(g, order, q_home, world, fine_step) or changed
        if not changed:
            break
        full = np.asarray(two_opt(Tm, np.r_[order, n]), dtype=np.int64)
        ends_home = int(full[-1]) == n
        order = full[full != n]
    # the figures only from checked nodes (the last round may have moved)
    _check_direct(g, order, q_home, world, fine_step)
    return order, ends_home


def _tour_paths(
    g: _TourGraph, order: NDArray[np.int64], timing: TimingModel
) -> tuple[list[NDArray[np.float64]], list[float], NDArray[np.float64]]:
    """Each move of ``order`` (straight where checked fine, else via home), its seconds, the radian matrix."""
    n = g.n
    paths: list[NDArray[np.float64]] = []
    secs: list[float] = []
    Dr = np.zeros((n, n))
    for a, b in zip(order[:-1].tolist(), order[1:].tolist(), strict=True):
        fine = g.straight[a, b] and (min(a, b), max(a, b)) in g.checked
        path = np.array([g.nodes[a], g.nodes[b]]) if fine else np.vstack([g.hubs[a], g.hubs[b][::-1][1:]])
        paths.append(path)
        secs.append(timing.motion_s(path))
        Dr[a, b] = Dr[b, a] = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
    return paths, secs, Dr


def _take_detours(
    order: NDArray[np.int64],
    nodes: NDArray[np.float64],
    paths: list[NDArray[np.float64]],
    secs: list[float],
    Dr: NDArray[np.float64],
    direct: NDArray[np.bool_],
    q_home: NDArray[np.float64],
    world: PlanningWorld,
    timing: TimingModel,
    step: float,
) -> NDArray[np.bool_]:
    """A tour's moves via home replaced in place (``paths``, ``secs``, ``Dr``) by a shorter way round,
    proven free at ``step`` (:func:`_detour`), where there is one and it is faster or via home is not
    provable (the arm's own planner then finds such a path; the model takes the detour's time).

    Returns:
        (len(paths),) True where a move took a detour.
    """
    detoured = np.zeros(len(paths), dtype=bool)
    for e, (a, b) in enumerate(zip(order[:-1].tolist(), order[1:].tolist(), strict=True)):
        if len(paths[e]) > 2:
            d = _detour(nodes[a], nodes[b], q_home, world, step)
            if d is not None:
                t_d = timing.motion_s(d)
                if t_d < secs[e] or not (direct[a] and direct[b]):
                    paths[e], secs[e], detoured[e] = d, t_d, True
                    Dr[a, b] = Dr[b, a] = float(np.linalg.norm(np.diff(d, axis=0), axis=1).sum())
    return detoured


def _on_s(q: NDArray[np.float64], after: NDArray[np.float64], timing: TimingModel) -> float:
    """Seconds of the straight move from ``q`` to the nearest (in time) of ``after`` (K, 6)."""
    return min(timing.motion_s(np.array([q, a])) for a in after)


DETOUR_PULLS = (0.25, 0.5, 0.75)  # how far towards home a detour's waypoints are pulled
DETOUR_GROUPS = ((1, 2), (3, 4, 5), (0,), (0, 1, 2))  # joints a detour may move first


def _detour(
    a: NDArray[np.float64],
    b: NDArray[np.float64],
    q_home: NDArray[np.float64],
    world: PlanningWorld,
    step: float,
) -> NDArray[np.float64] | None:
    """The fastest free way round for a straight move ``a → b`` that collides, or None.

    Candidates, every segment straight and checked at ``step``: through the midpoint pulled
    towards home by each of :data:`DETOUR_PULLS` (one waypoint), out towards home from ``a``
    and in from the same pull before ``b`` (two waypoints), and one joint group of
    :data:`DETOUR_GROUPS` moved first (shoulder and elbow, the wrist, the base). Via home itself is the pull 1 with
    both waypoints at home; these stay nearer the bin and stop once or twice less. Ranked by
    joint-space length (the longest joint's travel first), the first free one is taken.
    """
    mid = 0.5 * (a + b)
    cands = [np.array([a, mid + lam * (q_home - mid), b]) for lam in DETOUR_PULLS]
    cands += [np.array([a, a + lam * (q_home - a), b + lam * (q_home - b), b]) for lam in DETOUR_PULLS]
    for group in DETOUR_GROUPS:  # one joint group moves first, then the rest
        m = a.copy()
        m[list(group)] = b[list(group)]
        cands.append(np.array([a, m, b]))
    cands.sort(key=lambda P: float(np.abs(np.diff(P, axis=0)).max(axis=1).sum()))
    segs = [(P[i], P[i + 1]) for P in cands for i in range(len(P) - 1)]
    ok = world.motion_free(np.array([x for x, _ in segs]), np.array([y for _, y in segs]), step)
    at = 0
    for P in cands:
        k = len(P) - 1
        if ok[at : at + k].all():
            return P
        at += k
    return None


def _end_s(
    order: NDArray[np.int64],
    q: NDArray[np.float64],
    sel: NDArray[np.int64],
    parent: NDArray[np.int64],
    Q: NDArray[np.float64],
    q_home: NDArray[np.float64],
    timing: TimingModel,
    after: NDArray[np.float64] | None = None,
) -> float:
    """Seconds home from a tour's last node (configurations ``q`` per node): along its chain when
    its configuration is the reached one, else straight. ``after`` (the next surface's
    configurations at the station, no tuck): the move to the nearest of them instead."""
    last = int(order[-1])
    if after is not None and len(after):
        return _on_s(q[last], after, timing)
    k = int(sel[last - 1])
    if np.array_equal(q[last], Q[k]):
        return timing.motion_s(np.array([*chain_to_start(k, parent, Q), q_home]))
    return timing.motion_s(np.array([q[last], q_home]))


ALTERNATIVES = 10  # other configurations per viewpoint the refinement weighs


def _alternatives(
    q: NDArray[np.float64],
    near: NDArray[np.float64],
    robot: RobotModel,
    world: PlanningWorld,
    accept: Callable[[int, NDArray[np.float64]], bool] | None,
    half_turn: bool = False,
) -> NDArray[np.float64]:
    """Other free configurations that put the camera where ``q`` puts it (every IK branch, every
    2π turn of a ±2π joint), the :data:`ALTERNATIVES` nearest to the neighbours ``near`` (K, 6).

    ``half_turn``: also those of the camera turned by π about its optical axis — the same view
    when the principal point is the image centre (the image's rectangle onto itself): wrist 3
    then need not turn by π between neighbours whose rolls differ by π."""
    from cellctl.planning.reach import _WRAPPABLE, _rz

    T = robot.fk_cam(q[None])[0]
    S = robot.ik_cam(T)
    if half_turn:
        S2 = robot.ik_cam(T @ _rz(np.pi))
        S = np.vstack([S.reshape(-1, 6), S2.reshape(-1, 6)])
    if len(S) == 0:
        return np.zeros((0, 6))
    out = [S]
    for j in _WRAPPABLE:
        turned = [np.c_[A[:, :j], A[:, j] + k * 2 * np.pi, A[:, j + 1 :]] for A in out for k in (-1, 1)]
        out += turned
    A: NDArray[np.float64] = np.concatenate(out)
    A = A[np.all((A >= robot.q_min - 1e-9) & (A <= robot.q_max + 1e-9), axis=1)]
    A = A[np.abs(A - q).max(axis=1) > 1e-6]
    if len(A) == 0:
        return A
    A = A[np.argsort(np.abs(A[:, None, :] - near[None]).max(axis=2).sum(axis=1))]
    A = A[: 4 * ALTERNATIVES]
    A = A[world.robot_free(A)]
    if accept is not None and len(A):
        many = getattr(accept, "many", None)
        ok = many(A) if many is not None else np.array([accept(0, a) for a in A], dtype=bool)
        A = A[ok]
    return A[:ALTERNATIVES]


@dataclass
class _Choices:
    """Per tour position the candidate configurations (index 0: the picked one) and the moves' seconds.

    A move between candidates that is not the original one is barred once it fails the fine-step
    check and known good once it passes; its seconds are computed once.
    """

    alts: list[NDArray[np.float64]]
    secs: list[float]
    timing: TimingModel
    q_home: NDArray[np.float64]
    t_cache: dict[tuple[int, int, int], float] = field(default_factory=dict)
    barred: set[tuple[int, int, int]] = field(default_factory=set)
    good: set[tuple[int, int, int]] = field(default_factory=set)

    @property
    def m(self) -> int:
        return len(self.alts)

    def edge_s(self, pos: int, ia: int, ib: int) -> float:
        """Seconds of the move into position ``pos`` from candidate ``ia`` to candidate ``ib``."""
        if ia == 0 and ib == 0:
            return float(self.secs[pos - 1])
        key = (pos, ia, ib)
        if key in self.barred:
            return np.inf
        if key not in self.t_cache:
            self.t_cache[key] = self.timing.motion_s(np.array([self.alts[pos - 1][ia], self.alts[pos][ib]]))
        return self.t_cache[key]

    def home_s(self, ib: int) -> float:
        """Seconds of the move home from the last position's candidate ``ib``."""
        m = self.m
        key = (m, ib, -1)
        if key in self.barred:
            return np.inf
        if key not in self.t_cache:
            self.t_cache[key] = self.timing.motion_s(np.array([self.alts[m - 1][ib], self.q_home]))
        return self.t_cache[key]


def _refine_configurations(
    nodes: NDArray[np.float64],
    order: NDArray[np.int64],
    paths: list[NDArray[np.float64]],
    secs: list[float],
    robot: RobotModel,
    world: PlanningWorld,
    accept: Callable[[int, NDArray[np.float64]], bool] | None,
    timing: TimingModel,
    q_home: NDArray[np.float64],
    step: float,
    half_turn: bool = False,
) -> tuple[NDArray[np.float64], list[NDArray[np.float64]], list[float], int]:
    """The tour's order kept, each viewpoint's configuration chosen to make it fastest.

    A camera pose has up to 8 IK solutions, and the ±2π joints add turns of each: the one
    reachability picked (closest to the plan's median arm) is not the one nearest its tour
    neighbours. Dynamic programming over [picked, ≤ :data:`ALTERNATIVES` others] per viewpoint
    minimises the motion time of the tour and of its last move home; a move it uses that is
    not the original one must be straight and free at ``step`` (the sim arm's check): checked
    lazily, and a failing pair is barred and the programme re-solved (≤ 8 rounds, else the
    original configurations). Viewpoints next to a move that is not straight (via home) keep
    theirs. The camera poses (and so what is seen) do not change; with ``half_turn`` a camera may
    turn by π about its optical axis (:func:`_alternatives`: the same view for a centred image).

    Args:
        nodes: (n, 6) the tour's nodes: the start, then the selected viewpoints' configurations.
        order: node order of the tour (starting at 0).
        paths, secs: per tour edge (along ``order``) the joint path and its seconds.

    Returns:
        ``(configurations per node (n, 6), paths, seconds, viewpoints whose configuration changed)``.
    """
    seq = [int(k) for k in order]
    m = len(seq)
    if m < 2:
        return nodes, paths, secs, 0
    straight = [len(p) == 2 for p in paths]
    alts = [nodes[seq[0]][None]]
    for pos in range(1, m):
        q = nodes[seq[pos]]
        free_here = straight[pos - 1] and (pos == m - 1 or straight[pos])
        near = np.array([nodes[seq[pos - 1]], nodes[seq[pos + 1]] if pos < m - 1 else q_home])
        extra = _alternatives(q, near, robot, world, accept, half_turn) if free_here else np.zeros((0, 6))
        alts.append(np.vstack([q[None], extra]))
    ch = _Choices(alts, secs, timing, q_home)
    pick = _checked_picks(ch, world, step)
    out = nodes.copy()
    new_paths, new_secs = list(paths), list(secs)
    for pos in range(1, m):
        out[seq[pos]] = alts[pos][pick[pos]]
        if pick[pos - 1] or pick[pos]:
            new_paths[pos - 1] = np.array([alts[pos - 1][pick[pos - 1]], alts[pos][pick[pos]]])
            new_secs[pos - 1] = ch.edge_s(pos, pick[pos - 1], pick[pos])
    return out, new_paths, new_secs, int(sum(1 for k in pick if k))


def _checked_picks(ch: _Choices, world: PlanningWorld, step: float) -> list[int]:
    """The fastest candidate per position whose new moves are free at ``step`` (≤ 8 rounds, else all originals)."""
    m, alts, q_home = ch.m, ch.alts, ch.q_home
    pick = [0] * m
    for _round in range(8):
        pick = _fastest_picks(ch)
        todo = [(pos, pick[pos - 1], pick[pos]) for pos in range(1, m) if pick[pos - 1] or pick[pos]]
        if pick[m - 1]:
            todo.append((m, pick[m - 1], -1))
        todo = [k for k in todo if k not in ch.good]
        if not todo:
            break
        A = np.array([alts[p - 1][a] if b >= 0 else alts[m - 1][a] for p, a, b in todo])
        B = np.array([alts[p][b] if b >= 0 else q_home for p, a, b in todo])
        for key, ok in zip(todo, world.motion_free(A, B, step), strict=True):
            (ch.good if ok else ch.barred).add(key)
    else:
        pick = [0] * m
    return pick


def _fastest_picks(ch: _Choices) -> list[int]:
    """Dynamic programming over the candidates: the pick per position of the fastest tour and move home."""
    m, alts = ch.m, ch.alts
    cost = np.zeros(1)
    back: list[NDArray[np.int64]] = []
    for pos in range(1, m):
        C = np.array(
            [[cost[ia] + ch.edge_s(pos, ia, ib) for ib in range(len(alts[pos]))] for ia in range(len(alts[pos - 1]))]
        )
        back.append(C.argmin(axis=0))
        cost = C.min(axis=0)
    cost = cost + np.array([ch.home_s(ib) for ib in range(len(alts[m - 1]))])
    pick = [0] * m
    pick[m - 1] = int(np.argmin(cost))
    for pos in range(m - 1, 0, -1):
        pick[pos - 1] = int(back[pos - 1][pick[pos]])
    return pick


SHIFT_TRIES = 6  # whole-tour turns × directions, fastest first, whose new moves are checked


def _shift_tour(
    q_prev: NDArray[np.float64],
    nodes: NDArray[np.float64],
    order: NDArray[np.int64],
    paths: list[NDArray[np.float64]],
    secs: list[float],
    end_s: float,
    after: NDArray[np.float64] | None,
    robot: RobotModel,
    world: PlanningWorld,
    timing: TimingModel,
    q_home: NDArray[np.float64],
    step: float,
) -> tuple[NDArray[np.float64], NDArray[np.int64], list[NDArray[np.float64]], list[float]] | None:
    """The whole tour turned by 2π on some ±2π joints (and maybe run backwards), where that makes
    its two ends faster; or None.

    q and q + 2πk of the ±2π joints are the same arm, so the tour's own moves (every waypoint
    turned alike, or the same moves backwards) sweep the same space in the same time; only the
    move in from ``q_prev`` and the move out change. :func:`wrap_window` puts a station's
    viewpoints into one 2π window but picks the window by home, not by the tour's neighbours
    (case study seed 5 station 1: the external tour's base joint at 2.0…4.1 rad between an
    identification at −2.5 and an internal start at 0.4: 8.2 rad of base travel in and out).

    Scored: the move in + the move out — to the nearest of ``after`` (the next surface's
    configurations: its tour starts near one), or home (``after`` None) — against
    ``secs[0] + end_s`` as planned. The move in is straight where that is free at ``step``,
    else the fastest free way round (:func:`_detour`, bent towards the nearest turn of home); the
    straight move home from the new last viewpoint (the next tour's way home from its start, or
    the tuck) must be free.

    Returns:
        ``(nodes, order, paths, seconds)`` of the new tour, or None (no faster free one).
    """
    ends = {False: (int(order[1]), int(order[-1])), True: (int(order[-1]), int(order[1]))}
    ctx = _ShiftEnds(q_prev, nodes, ends, after, robot, timing, q_home, float(secs[0]) + float(end_s))
    cands = _shift_candidates(ctx, order, paths)
    if not cands:
        return None
    best = _best_shift(ctx, cands, world, step)
    if best is None:
        return None
    _t, sh, back, move_in = best
    out = nodes.copy()
    out[1:] += sh
    rest = [p + sh for p in paths[1:]]
    rest_s = list(secs[1:])
    new_order = order.copy()
    if back:
        new_order = np.r_[order[:1], order[1:][::-1]]
        rest, rest_s = [p[::-1] for p in rest[::-1]], rest_s[::-1]
    return out, new_order, [move_in, *rest], [timing.motion_s(move_in), *rest_s]


@dataclass(frozen=True)
class _ShiftEnds:
    """What scores a turned tour: its ends (first, last node; per direction), the moves in and out, the bar."""

    q_prev: NDArray[np.float64]
    nodes: NDArray[np.float64]
    ends: dict[bool, tuple[int, int]]
    after: NDArray[np.float64] | None
    robot: RobotModel
    timing: TimingModel
    q_home: NDArray[np.float64]
    base: float
    """Seconds of the move in and the move out as planned."""

    def out_s(self, q: NDArray[np.float64]) -> float:
        """Seconds of the move out of ``q``: to the nearest of ``after``, or home."""
        if self.after is None or len(self.after) == 0:
            return self.timing.motion_s(np.array([q, self.q_home]))
        return _on_s(q, self.after, self.timing)

    def near(self, a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
        """Home turned by 2π on the ±2π joints nearest to between ``a`` and ``b`` (the same arm:
        a way round a turned tour's move in bends towards it, not back across a turn)."""
        from cellctl.planning.reach import _WRAPPABLE

        h = self.q_home.copy()
        j = list(_WRAPPABLE)
        h[j] += 2.0 * np.pi * np.round((0.5 * (a[j] + b[j]) - h[j]) / (2.0 * np.pi))
        return np.where((h >= self.robot.q_min) & (h <= self.robot.q_max), h, self.q_home)


def _shift_candidates(
    ctx: _ShiftEnds, order: NDArray[np.int64], paths: list[NDArray[np.float64]]
) -> list[tuple[float, NDArray[np.float64], bool]]:
    """Turns × directions within the joint limits whose straight ends beat the plan, fastest first (≤ SHIFT_TRIES)."""
    from itertools import product

    from cellctl.planning.reach import _WRAPPABLE

    nodes, robot = ctx.nodes, ctx.robot
    vps = np.array([nodes[int(k)] for k in order[1:]])
    way = np.vstack([vps, *paths[1:]]) if len(paths) > 1 else vps
    cands: list[tuple[float, NDArray[np.float64], bool]] = []
    for ks in product((-1, 0, 1), repeat=len(_WRAPPABLE)):
        sh = np.zeros(6)
        sh[list(_WRAPPABLE)] = 2.0 * np.pi * np.array(ks, dtype=np.float64)
        if any(ks) and not np.all((way + sh >= robot.q_min - 1e-9) & (way + sh <= robot.q_max + 1e-9)):
            continue
        for back in (False, True) if len(order) > 2 else (False,):
            if not any(ks) and not back:
                continue  # the tour as planned
            first, last = ctx.ends[back]
            t = ctx.timing.motion_s(np.array([ctx.q_prev, nodes[first] + sh])) + ctx.out_s(nodes[last] + sh)
            if t < ctx.base - 1e-3:  # a lower bound: a detour in only adds
                cands.append((t, sh, back))
    cands.sort(key=lambda c: c[0])
    return cands[:SHIFT_TRIES]


def _best_shift(
    ctx: _ShiftEnds, cands: list[tuple[float, NDArray[np.float64], bool]], world: PlanningWorld, step: float
) -> tuple[float, NDArray[np.float64], bool, NDArray[np.float64]] | None:
    """The fastest candidate whose move home is free at ``step`` and whose move in is (straight or round)."""
    nodes, ends, q_prev, q_home = ctx.nodes, ctx.ends, ctx.q_prev, ctx.q_home
    A = np.array([x for _, sh, bk in cands for x in (q_prev, nodes[ends[bk][1]] + sh)])
    B = np.array([x for _, sh, bk in cands for x in (nodes[ends[bk][0]] + sh, q_home)])
    ok = world.motion_free(A, B, step).reshape(-1, 2)
    best: tuple[float, NDArray[np.float64], bool, NDArray[np.float64]] | None = None
    for i, (t, sh, back) in enumerate(cands):
        if best is not None and t >= best[0]:
            break
        if not ok[i, 1]:
            continue
        first, last = ends[back]
        q_in = nodes[first] + sh
        move_in = np.array([q_prev, q_in]) if ok[i, 0] else _detour(q_prev, q_in, ctx.near(q_prev, q_in), world, step)
        if move_in is None:
            continue
        t_real = ctx.timing.motion_s(move_in) + ctx.out_s(nodes[last] + sh)
        if t_real < ctx.base - 1e-3 and (best is None or t_real < best[0]):
            best = (t_real, sh, back, move_in)
    return best


def _half_turned(robot: RobotModel, Q0: NDArray[np.float64], Q1: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(n,) True where ``Q1`` puts the camera of ``Q0`` turned by π about its optical axis."""
    if len(Q0) == 0:
        return np.zeros(0, dtype=bool)
    x0, x1 = robot.fk_cam(Q0)[:, :3, 0], robot.fk_cam(Q1)[:, :3, 0]
    turned: NDArray[np.bool_] = np.einsum("ij,ij->i", x0, x1) < 0.0
    return turned
