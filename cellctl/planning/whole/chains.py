"""Chains home and the selection's rules: which chain viewpoints a tour must visit, what makes up
for those left out, the coverage floor, the gain rule.

A viewpoint joined to home through others (:func:`cellctl.planning.whole.connection.connect`) is
reached along its chain of straight motions. ``chains="all"`` visits every chain
(:func:`_with_ancestors`); ``"needed"`` only where a tour needs it (:func:`_with_needed_ancestors`)
and makes up what the others saw (:func:`_needed_and_made_up`); a tour with unverified moves takes
chains back (:func:`_readd_chains`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from cellctl.planning.collision import PlanningWorld
from cellctl.planning.whole.connection import CHAIN_ROUNDS, COARSE_STEP_RAD, Connected, chain_to_start

__all__: list[str] = []


def _with_needed_ancestors(
    cols: NDArray[np.int64],
    owner: NDArray[np.int64],
    local: NDArray[np.int64],
    cons: list[Connected],
    worlds: list[PlanningWorld],
    q_home: NDArray[np.float64],
    fine_step: float,
    straight_cache: list[dict[tuple[int, int], bool]] | None = None,
) -> NDArray[np.int64]:
    """The selection plus the viewpoints on selected ones' chains home that the tour needs.

    A chained viewpoint (joined to home through others) is visited by straight motions from
    its tour neighbours. Its chain's viewpoints are added (visited and captured: a move plus
    settle and capture each) only where the selection does not give it two neighbours it
    joins straight (one for a way in, one out) or where its group of such neighbours holds no
    viewpoint joined straight to home; otherwise the tour reaches it through other selected
    viewpoints. Checked at :data:`COARSE_STEP_RAD`, like the chains; the tour checks its moves
    again at the sim arm's step. The tour ends where the arm tucks home by one straight motion
    free at ``fine_step``: a station's share holds one such viewpoint (nearest home first),
    else a chain's root is added, else every chain (the rule before). ``straight_cache`` (one
    dict per station) keeps the pair checks between calls on a growing selection.
    """
    col_of = {(int(o), int(j)): c for c, (o, j) in enumerate(zip(owner, local, strict=True))}
    out: set[int] = set()
    for k, (con, world) in enumerate(zip(cons, worlds, strict=True)):
        S = {int(local[c]) for c in cols if int(owner[c]) == k}
        if not S:
            continue
        par, Q = con.parent, con.reached.q
        # pairs already checked (the make-up and the floor call this again on a grown selection)
        straight: dict[tuple[int, int], bool] = {} if straight_cache is None else straight_cache[k]
        for _round in range(4 * CHAIN_ROUNDS + 4):
            members = sorted(S)
            todo = [(a, b) for i, a in enumerate(members) for b in members[i + 1 :] if (a, b) not in straight]
            if todo:
                ok = world.motion_free(Q[[a for a, _ in todo]], Q[[b for _, b in todo]], COARSE_STEP_RAD)
                straight.update(zip(todo, ok.tolist(), strict=True))
            nb = {a: [b for b in members if b != a and straight[(min(a, b), max(a, b))]] for a in members}
            add = {int(par[a]) for a in members if par[a] >= 0 and len(nb[a]) < 2}
            # groups of straight neighbours with no viewpoint joined straight to home: enter by a chain
            seen: set[int] = set()
            for a in members:
                if a in seen:
                    continue
                group, stack = [], [a]
                seen.add(a)
                while stack:
                    x = stack.pop()
                    group.append(x)
                    for y in nb[x]:
                        if y not in seen:
                            seen.add(y)
                            stack.append(y)
                if all(par[x] >= 0 for x in group):
                    add.add(int(par[min(group, key=lambda x: len(chain_to_start(x, par, Q)))]))
            add -= S
            if not add:
                break
            S |= add
        else:  # no fixed point within the rounds: every chain, as before
            for a in list(S):
                S.update(int(x) for x in _chain_ids(a, par))
        if not _has_tuck(S, par, Q, world, q_home, fine_step):
            roots = {int(_chain_ids(a, par)[-1]) for a in S} - S
            if not _has_tuck(roots, par, Q, world, q_home, fine_step, add_to=S):
                for a in list(S):
                    S.update(int(x) for x in _chain_ids(a, par))
        out.update(col_of[(k, a)] for a in S)
    return np.array(sorted(out), dtype=np.int64)


def _needed_and_made_up(
    selected: NDArray[np.int64],
    every_chain: NDArray[np.int64],
    C: NDArray[np.bool_],
    area: NDArray[np.float64],
    close: Callable[[NDArray[np.int64]], NDArray[np.int64]],
    min_gain_m2: float,
    rounds: int = 3,
) -> tuple[NDArray[np.int64], int]:
    """The selection with only the chain viewpoints its tour needs, plus what makes up the rest.

    Every chain visited (``every_chain``: ``chains="all"``) captures at each chain viewpoint
    too, and that area is part of the plan's coverage. Visiting only the needed ones (``close``:
    :func:`_with_needed_ancestors`) loses what the others alone saw, so Greedy Area runs again
    over exactly those faces (any viewpoint of the chosen stations, each adding ≥ ``min_gain_m2``
    of them, the selection's own rule), the needed chains of the additions are added, and so on
    (≤ ``rounds``). Usually a few well-placed viewpoints see what a chain's stops saw on the way.

    Returns:
        The columns to visit, and how many of them the make-up added (chains included).
    """
    from cellctl.planning.select import greedy_area

    target = cast(NDArray[np.bool_], C[:, every_chain].any(axis=1))  # what visiting every chain sees
    cols = close(selected)
    n_needed = len(cols)
    for _ in range(rounds):
        lost = target & ~C[:, cols].any(axis=1)
        if float(area[lost].sum()) < max(min_gain_m2, 1e-12):
            break
        Cl = C & lost[:, None]
        Cl[:, cols] = False
        add = [int(j) for j in greedy_area(Cl, area)]
        seen = np.zeros(len(area), dtype=bool)
        keep = []
        for j in add:  # the selection's rule: a viewpoint must add min_gain_m2 of what is lost
            if float(area[Cl[:, j] & ~seen].sum()) < min_gain_m2:
                break
            seen |= Cl[:, j]
            keep.append(j)
        if not keep:
            break
        cols = close(np.union1d(cols, keep).astype(np.int64))
    return cols, len(cols) - n_needed


def _fill_to_floor(
    cols: NDArray[np.int64],
    C: NDArray[np.bool_],
    area: NDArray[np.float64],
    floor_m2: float,
    close: Callable[[NDArray[np.int64]], NDArray[np.int64]],
    batch: int = 3,
) -> tuple[NDArray[np.int64], int]:
    """Grow the selection, Greedy Area over what it does not see, until it sees ``floor_m2``.

    The gain rule (``view_min_gain_pct``) trades slivers for cycle time; a plant's coverage
    requirement (``planner.whole.min_bound_pct``) is the other side of that trade: below it, the
    best next viewpoints are taken whatever they add (``batch`` at a time, then ``close`` adds
    what their tours need: their chains), until the floor is reached or nothing adds area.

    Returns:
        The columns, and how many were added (chains included).
    """
    n0 = len(cols)
    for _ in range(200):
        seen = C[:, cols].any(axis=1) if len(cols) else np.zeros(C.shape[0], dtype=bool)
        if float(area[seen].sum()) >= floor_m2:
            break
        left = area * ~seen
        gain = left @ C.astype(np.float64)
        gain[cols] = 0.0
        best = [int(j) for j in np.argsort(-gain, kind="stable")[:batch] if gain[j] > 0]
        if not best:
            break
        # one at a time within the batch: the second's gain after the first's
        take = []
        for j in best:
            if float(left[C[:, j]].sum()) > 0:
                take.append(j)
                left = left * ~C[:, j]
        cols = close(np.union1d(cols, take).astype(np.int64))
    return cols, len(cols) - n0


def _has_tuck(
    nodes: set[int],
    par: NDArray[np.int64],
    Q: NDArray[np.float64],
    world: PlanningWorld,
    q_home: NDArray[np.float64],
    step: float,
    add_to: set[int] | None = None,
) -> bool:
    """True when one of ``nodes`` joined straight to home moves home straight and free at ``step``
    (checked nearest home first, a few at a time); ``add_to`` gets the first such node."""
    direct = sorted((a for a in nodes if par[a] < 0), key=lambda a: float(np.abs(Q[a] - q_home).max()))
    for at in range(0, len(direct), 3):
        part = direct[at : at + 3]
        ok = world.motion_free(Q[part], np.repeat(q_home[None], len(part), axis=0), step)
        if ok.any():
            if add_to is not None:
                add_to.add(part[int(np.argmax(ok))])
            return True
    return False


def _readd_chains(
    sel: NDArray[np.int64],
    stuck: NDArray[np.int64],
    parent: NDArray[np.int64],
    first: tuple[Any, ...],
    tour: Callable[[NDArray[np.int64]], tuple[Any, ...]],
) -> tuple[NDArray[np.int64], tuple[Any, ...]]:
    """The selection and tour to keep when ``first`` (the tour of ``sel``) has unverified moves.

    The chain viewpoints left out make moves via home the arm may refuse; visiting a chain makes
    its moves straight. First only the chains of the ``stuck`` viewpoints (those whose way home
    is not free at the sim arm's step): each chain viewpoint costs a move + settle + capture
    (~2 s), and all of them cost seed 2 of the case study 8 viewpoints. Then every chain, as
    before, unless the stuck ones' chains already made every move verified. The tour with the
    fewest unverified moves is kept, then the shorter one (``first`` when none is better).
    """

    def grown(ids: NDArray[np.int64]) -> NDArray[np.int64]:
        return np.unique(np.concatenate([sel, *[_chain_ids(int(a), parent) for a in ids]]))

    best_sel, best = sel, first
    tried = {tuple(sel.tolist())}
    for ids in (stuck, sel):
        cand = grown(ids)
        if tuple(cand.tolist()) in tried:
            continue
        tried.add(tuple(cand.tolist()))
        got = tour(cand)
        if got[5] < best[5] or (got[5] == best[5] and best is not first and sum(got[3]) < sum(best[3])):
            best_sel, best = cand, got
        if best[5] == 0:
            break
    return best_sel, tuple(best[:6])


def _chain_ids(k: int, parent: NDArray[np.int64]) -> list[int]:
    out = []
    while k >= 0:
        out.append(k)
        k = int(parent[k])
    return out


def _with_ancestors(
    cols: NDArray[np.int64], owner: NDArray[np.int64], local: NDArray[np.int64], parents: list[NDArray[np.int64]]
) -> NDArray[np.int64]:
    """The selection plus every viewpoint on a selected one's chain home (same station).

    A viewpoint joined to home through others is reached by the straight motions of its chain:
    the cycle visits (and captures at) those viewpoints too, so each of its moves is one the sim
    arm makes straight.
    """
    col_of = {(int(o), int(j)): c for c, (o, j) in enumerate(zip(owner, local, strict=True))}
    out = {int(c) for c in cols}
    for c in cols:
        k, j = int(owner[c]), int(parents[int(owner[c])][int(local[c])])
        while j >= 0:
            out.add(col_of[(k, j)])
            j = int(parents[k][j])
    return np.array(sorted(out), dtype=np.int64)


def _worthwhile(
    greedy: NDArray[np.int64], C: NDArray[np.bool_], area: NDArray[np.float64], bound_m2: float, min_gain_pct: float
) -> NDArray[np.int64]:
    """The Greedy Area prefix whose every viewpoint adds at least ``min_gain_pct`` % of the bound.

    Greedy's tail adds slivers (0.1 % of the surface per viewpoint) at a full move + settle +
    capture each; the rule trades them for cycle time, and the area given up is reported.
    """
    if min_gain_pct <= 0 or len(greedy) == 0:
        return greedy
    covered = np.zeros(C.shape[0], dtype=bool)
    keep = 0
    for k, j in enumerate(greedy):
        gain = float(area[C[:, j] & ~covered].sum())
        if gain < min_gain_pct / 100.0 * bound_m2:
            break
        covered |= C[:, j]
        keep = k + 1
    return greedy[: max(1, keep)]
