"""Stages 4 and 5 of a whole-bin plan: the viewpoint selection over the chosen stations, and the
exact (station, viewpoint) cover of what it sees.

Per surface, Greedy Area (with the gain rule) and simulated annealing select over every chosen
station's connected viewpoints at once; the chain viewpoints the tours need are added, what they
leave out is made up, and the coverage floor is filled (:mod:`cellctl.planning.whole.chains`).
The exact cover (a MILP over every evaluated station's columns) is reported beside the plan.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import PlanningError
from cellctl.planning.whole.chains import (
    _fill_to_floor,
    _needed_and_made_up,
    _with_ancestors,
    _with_needed_ancestors,
    _worthwhile,
)
from cellctl.planning.whole.state import StationEval, WholeState
from cellctl.surface import SURFACES

__all__ = ["exact_cover", "exact_cover_columns", "must_of", "select_viewpoints"]


def select_viewpoints(
    ws: WholeState,
    chosen_ev: list[StationEval],
) -> tuple[dict[str, list[NDArray[np.int64]]], dict[str, int], dict[str, int], dict[str, float]]:
    """Per surface the chosen stations' shares (local columns), Greedy's length, counts, seen m²."""
    from cellctl.planning.select import greedy_area, simulated_annealing, visible_area

    params, p0 = ws.params, ws.p0
    picked: dict[str, list[NDArray[np.int64]]] = {}
    greedy_n: dict[str, int] = {}
    cnt: dict[str, int] = {}
    seen_m2: dict[str, float] = {}
    for surf in ws.shared:
        blocks = [e.vis[surf].C for e in chosen_ev]
        C = np.hstack(blocks)
        owner = np.concatenate([np.full(b.shape[1], k) for k, b in enumerate(blocks)])
        local = np.concatenate([np.arange(b.shape[1]) for b in blocks])
        a = ws.areas[surf]
        picked[surf] = [np.zeros(0, np.int64) for _ in chosen_ev]
        seen_m2[surf] = 0.0
        if C.shape[1] == 0:
            continue
        rng = np.random.default_rng([p0.seed, 17, SURFACES.index(surf)])
        ga = _worthwhile(greedy_area(C, a), C, a, ws.bounds[surf], params.view_min_gain_pct)
        sa = simulated_annealing(C, a, ga, p0.sa_pct, rng, iterations=p0.sa_iterations)
        cons_s = [e.con[surf] for e in chosen_ev]
        # the selection plus the chain viewpoints its tours visit; the pair checks are kept
        # between calls (the make-up and the floor call it again on a grown selection)
        if params.chains == "needed":
            close = partial(
                _with_needed_ancestors,
                owner=owner,
                local=local,
                cons=cons_s,
                worlds=[e.setups[surf].world for e in chosen_ev],
                q_home=ws.q_home,
                fine_step=ws.step,
                straight_cache=[{} for _ in chosen_ev],
            )
        else:
            close = partial(_with_ancestors, owner=owner, local=local, parents=[c.parent for c in cons_s])
        if params.chains == "needed":
            every_chain = _with_ancestors(sa.selected, owner, local, [c.parent for c in cons_s])
            chosen_cols, cnt[f"made_up_{surf}"] = _needed_and_made_up(
                sa.selected, every_chain, C, a, close, params.view_min_gain_pct / 100.0 * ws.bounds[surf]
            )
        else:
            chosen_cols = close(sa.selected)
        floor = params.min_bound_pct.get(surf, 0.0) / 100.0 * ws.bounds[surf]
        if floor > 0:
            chosen_cols, cnt[f"floor_added_{surf}"] = _fill_to_floor(chosen_cols, C, a, floor, close)
        cnt[f"chain_added_{surf}"] = len(chosen_cols) - len(sa.selected)
        greedy_n[surf] = len(ga)
        picked[surf] = [np.sort(local[chosen_cols][owner[chosen_cols] == k]) for k in range(len(chosen_ev))]
        seen_m2[surf] = visible_area(C, a, chosen_cols)
    return picked, greedy_n, cnt, seen_m2


def exact_cover_columns(ws: WholeState) -> None:
    """The exact cover's columns over every evaluated station (``ws.cols``) and each surface's row
    offset (``ws.offs``, ``ws.off`` rows in all): the others' optimistic masks could not beat the
    chosen ones' coverage."""
    off = 0
    for surf in ws.shared:
        ws.offs[surf] = off
        off += len(ws.areas[surf])
    ws.off = off
    for e in ws.evals:
        for surf in ws.shared:
            Cs = e.vis[surf].C
            for j in range(Cs.shape[1]):
                col = np.zeros(off, dtype=bool)
                col[ws.offs[surf] : ws.offs[surf] + len(ws.areas[surf])] = Cs[:, j]
                ws.cols.append((e.cand.index, col))


def must_of(
    ws: WholeState, chosen_ev: list[StationEval], picked: dict[str, list[NDArray[np.int64]]]
) -> NDArray[np.bool_]:
    """The exact cover's rows to cover: every face the selection ``picked`` at ``chosen_ev`` sees."""
    must = np.zeros(ws.off, dtype=bool)
    for surf in ws.shared:
        for k, e in enumerate(chosen_ev):
            sel = picked[surf][k]
            if len(sel):
                must[ws.offs[surf] : ws.offs[surf] + len(ws.areas[surf])] |= e.vis[surf].C[:, sel].any(axis=1)
    return must


def exact_cover(ws: WholeState, must: NDArray[np.bool_], limit_s: float | None = None) -> Any:
    """The exact (station, viewpoint) cover of ``must`` (``limit_s``: the MILP's time limit, default
    ``exact_time_limit_s``), or None where the MILP gives none."""
    from cellctl.planning.stations import exact_station_cover

    try:
        return exact_station_cover(ws.cols, must, ws.params.exact_time_limit_s if limit_s is None else limit_s)
    except PlanningError:
        return None
