"""The cycle budget: a whole-bin plan over the plant's takt (``cycle_budget_s``) takes one station
fewer where that set still sees every surface's floor, then gives up the viewpoints that see least
per modelled second while the floors hold (:func:`meet_budget`); a plan within it is not touched.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.planning.whole.evaluation import _ring_order
from cellctl.planning.whole.records import TimingModel
from cellctl.planning.whole.selection import exact_cover, must_of, select_viewpoints
from cellctl.planning.whole.state import WholeState
from cellctl.planning.whole.tours import run_tours, summarize

__all__ = ["BUDGET_EXACT_S", "BUDGET_ROUNDS", "BUDGET_SLACK_S", "FEWER_TRIES", "meet_budget"]


def meet_budget(ws: WholeState) -> None:
    """Over the plant's takt: first one station fewer (the best such set, if its selection still
    sees every surface's floor), then the viewpoints that see least per second (≤ :data:`BUDGET_ROUNDS`
    trim-and-tour rounds). Updates ``ws.res`` (the run kept), ``ws.chosen_ev``, ``ws.picked``,
    ``ws.greedy_n``, ``ws.counts`` and ``ws.exact``."""
    budget, floors, shared = ws.params.cycle_budget_s, ws.floors, ws.shared
    if not (budget > 0 and ws.res["cycle"] > budget):
        return
    res = ws.res
    if len(ws.chosen_ev) > 1 and ws.params.estimate_thin == 1:
        # the sets one station smaller whose stations can see every floor, most seen first
        for sub in _fewer_sets([e.seen for e in ws.evals], ws.areas, ws.bounds, floors, len(ws.chosen_ev) - 1):
            fewer = _ring_order([ws.evals[i] for i in sub])
            p_b, g_b, c_b, seen_b = select_viewpoints(ws, fewer)
            if not all(seen_b[s] >= floors[s] - 1e-12 for s in shared):
                continue
            keep = (ws.chosen_ev, ws.picked, ws.sel_counts)
            ws.chosen_ev, ws.picked, ws.sel_counts = fewer, p_b, c_b
            res_b = run_tours(ws, False)
            if _better(res_b, res, floors):
                res, ws.greedy_n = res_b, g_b
                ws.counts["budget_fewer_stations"] = 1
            else:
                ws.chosen_ev, ws.picked, ws.sel_counts = keep
            break
    caps: dict[int, int] = {}  # stations whose trimmed tour was not better: at most this many out next
    for _round in range(BUDGET_ROUNDS):
        if res["cycle"] <= budget:
            break
        trimmed = _trim_to_budget(res, budget, floors, ws.areas, ws.params.timing, ws.q_home, caps)
        if trimmed is None:
            break
        ws.chosen_ev, ws.picked = res["chosen_ev"], trimmed
        ws.sel_counts = res["sel_counts"]
        caps_before = dict(caps)
        res_t = _mixed(ws, run_tours(ws, False, reuse=res), res, caps)
        if not _better(res_t, res, floors):
            if caps == caps_before:
                break
            continue  # every trimmed station refused: again with at most half as many out of them
        ws.counts["budget_trimmed"] = (
            ws.counts.get("budget_trimmed", 0)
            + sum(len(x) for v in res["picked"].values() for x in v)
            - sum(len(x) for v in res_t["picked"].values() for x in v)
        )
        res = res_t
    ws.res = res
    ws.chosen_ev = res["chosen_ev"]
    ws.counts.update(res["sel_counts"])
    final_must = must_of(ws, ws.chosen_ev, res["selection"])
    if not np.array_equal(final_must, ws.must_now):  # the exact cover of the selection kept
        ws.exact = exact_cover(ws, final_must, min(ws.params.exact_time_limit_s, BUDGET_EXACT_S))


def _mixed(ws: WholeState, new: dict[str, Any], old: dict[str, Any], caps: dict[int, int]) -> dict[str, Any]:
    """Per station the trimmed tour where it is shorter with no more unverified moves, else the old one
    (stations are independent; putting a station's viewpoints back only adds coverage). A station
    toured again and refused gets at most half as many out next round (``caps``)."""
    jobs: list[Any] = []
    selection: dict[str, list[NDArray[np.int64]]] = {surf: [] for surf in old["selection"]}
    for k, (jn, jo) in enumerate(zip(new["jobs"], old["jobs"], strict=True)):
        take = jn[0].cycle_s < jo[0].cycle_s and jn[2].get("unverified_moves", 0) <= jo[2].get("unverified_moves", 0)
        src = new if take else old
        jobs.append(jn if take else jo)
        for surf in selection:
            selection[surf].append(src["selection"][surf][k])
        if jn is not jo and not take:  # toured again and refused: next round at most half as many out
            n_out = max(0, sum(len(old["picked"][s][k]) - len(new["selection"][s][k]) for s in selection))
            caps[k] = min(caps.get(k, n_out), n_out) // 2
    return summarize(ws, jobs, selection, old["chosen_ev"], None, old["sel_counts"])


FEWER_TRIES = 2  # station sets one smaller a plan over its budget selects viewpoints for
BUDGET_ROUNDS = 5  # trim-and-tour rounds of a plan over its budget
BUDGET_EXACT_S = 2.0  # the exact cover of a selection the budget changed: its MILP's time limit


def _fewer_sets(
    seen: list[dict[str, NDArray[np.bool_]]],
    areas: dict[str, NDArray[np.float64]],
    bounds: dict[str, float],
    floors: dict[str, float],
    size: int,
) -> list[tuple[int, ...]]:
    """Station sets of ``size`` whose stations' connected views see every surface's floor (m²),
    the most seen (sum of bound fractions) first, at most :data:`FEWER_TRIES`: what a plan over
    its budget tries with one station fewer (the selection decides whether a set holds)."""
    import itertools

    out: list[tuple[float, tuple[int, ...]]] = []
    for sub in itertools.combinations(range(len(seen)), size):
        total, ok = 0.0, True
        for surf, a in areas.items():
            m = np.zeros(len(a), dtype=bool)
            for i in sub:
                m |= seen[i][surf]
            got = float(a[m].sum())
            ok &= got >= floors.get(surf, 0.0) - 1e-12
            total += got / bounds[surf] if bounds[surf] > 0 else 0.0
        if ok:
            out.append((-total, sub))
    return [sub for _t, sub in sorted(out)[:FEWER_TRIES]]


def _better(new: dict[str, Any], old: dict[str, Any], floors: dict[str, float]) -> bool:
    """A tour run that beats ``old`` for the budget: shorter, no more unverified moves, floors seen."""
    return (
        new["cycle"] < old["cycle"] - 1e-6
        and new["counts"].get("unverified_moves", 0) <= old["counts"].get("unverified_moves", 0)
        and all(new["seen"][s][0] >= floors.get(s, 0.0) - 1e-12 for s in new["seen"])
    )


BUDGET_SLACK_S = 2.0  # the trim aims this far below the budget (its savings are estimates)


def _trim_to_budget(
    res: dict[str, Any],
    budget_s: float,
    floors: dict[str, float],
    areas: dict[str, NDArray[np.float64]],
    timing: TimingModel,
    q_home: NDArray[np.float64],
    caps: dict[int, int] | None = None,
) -> dict[str, list[NDArray[np.int64]]] | None:
    """The shares without the viewpoints that see least per modelled second, down to the budget.

    A plant sizes its line by takt time: above ``budget_s`` a surface that sees more than its
    floor (``floors``, m²) gives up viewpoints. Each round takes out the viewpoint with the least
    area only it sees per second it costs — its settle and capture, and its moves in and out less
    the straight move between its tour neighbours (an estimate; the tours are run again) — while
    its surface still sees its floor, until the estimate is :data:`BUDGET_SLACK_S` below the
    budget. A viewpoint on another selected one's chain home is kept, and at most ``caps[k]``
    viewpoints leave station (rank) k (a station whose last trim was refused). None: nothing to take out.
    """
    per_vp = timing.settle_s + timing.capture_s
    chosen_ev, picked = res["chosen_ev"], res["picked"]
    surfs = list(picked)
    cnt = {
        s: sum(
            (chosen_ev[k].vis[s].C[:, picked[s][k]].sum(axis=1) for k in range(len(chosen_ev)) if len(picked[s][k])),
            np.zeros(len(areas[s]), dtype=np.int64),
        )
        for s in surfs
    }
    seen = {s: float(areas[s][cnt[s] > 0].sum()) for s in surfs}
    # per station: its visits in order (surface, column, joints) and each one's move in
    seqs: list[list[list[Any]]] = []
    starts: list[NDArray[np.float64]] = []
    for st in res["stations"]:
        seq: list[list[Any]] = []
        q_prev = st.identify_q if st.identify_q is not None else q_home
        starts.append(q_prev)
        for surf, p in st.plans.items():
            for v in p.viewpoints:
                path = np.vstack([q_prev[None], v.approach, v.q[None]])
                seq.append([surf, int(v.candidate), v.q, timing.motion_s(path)])
                q_prev = v.q
        seqs.append(seq)

    def straight(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
        return timing.motion_s(np.array([a, b]))

    removed: dict[str, list[set[int]]] = {s: [set() for _ in chosen_ev] for s in surfs}
    est = float(res["cycle"])
    while est > budget_s - BUDGET_SLACK_S:
        best: tuple[float, float, int, int] | None = None
        for k, seq in enumerate(seqs):
            if caps is not None and sum(len(r[k]) for r in removed.values()) >= caps.get(k, len(seq) + 1):
                continue
            for i, (surf, col, q, t_in) in enumerate(seq):
                par = chosen_ev[k].con[surf].parent
                share = [c for sf, c, _q, _t in seq if sf == surf]
                if any(int(par[c]) == col for c in share):
                    continue  # on another one's chain home
                Ck = chosen_ev[k].vis[surf].C[:, col]
                only = float(areas[surf][Ck & (cnt[surf] == 1)].sum())
                if seen[surf] - only < floors.get(surf, 0.0) - 1e-12:
                    continue
                prev = seq[i - 1][2] if i > 0 else starts[k]
                nxt = seq[i + 1][2] if i + 1 < len(seq) else q_home
                t_out = seq[i + 1][3] if i + 1 < len(seq) else straight(q, q_home)
                saved = per_vp + t_in + t_out - straight(prev, nxt)
                if saved <= 0:
                    continue
                key = (only / saved, -saved, k, i)
                if best is None or key < best:
                    best = key
        if best is None:
            break
        _r, neg_saved, k, i = best
        surf, col, _q, _t = seqs[k][i]
        Ck = chosen_ev[k].vis[surf].C[:, col]
        cnt[surf] = cnt[surf] - Ck
        seen[surf] = float(areas[surf][cnt[surf] > 0].sum())
        removed[surf][k].add(col)
        prev = seqs[k][i - 1][2] if i > 0 else starts[k]
        del seqs[k][i]
        if i < len(seqs[k]):
            seqs[k][i][3] = straight(prev, seqs[k][i][2])
        est += neg_saved
    if not any(r for v in removed.values() for r in v):
        return None
    return {
        s: [np.array(sorted(set(picked[s][k].tolist()) - removed[s][k]), dtype=np.int64) for k in range(len(chosen_ev))]
        for s in surfs
    }
