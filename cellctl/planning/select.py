"""Viewpoint selection: Greedy Area, Simulated Annealing (paper eq. 3–5), exact set cover bound."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["SAResult", "greedy_area", "min_set_cover", "simulated_annealing", "visible_area"]


def visible_area(C: NDArray[np.bool_], area: NDArray[np.float64], cols: NDArray[np.int64] | list[int]) -> float:
    """Area (m²) of the faces seen by at least one of the viewpoints ``cols``."""
    cols = np.asarray(cols, dtype=np.int64)
    if len(cols) == 0:
        return 0.0
    return float(area[C[:, cols].any(axis=1)].sum())


def greedy_area(C: NDArray[np.bool_], area: NDArray[np.float64]) -> NDArray[np.int64]:
    """Greedy Area: repeatedly take the viewpoint that adds the most still-unseen area.

    Stops when every face visible from some viewpoint is covered, so the result sees exactly
    the area of the whole set. Ties go to the lower index (deterministic).

    Returns:
        Selected column indices in selection order.
    """
    Cf = C.astype(np.float64)
    left = area * C.any(axis=1)
    chosen: list[int] = []
    while left.sum() > 0:
        gain = left @ Cf
        j = int(np.argmax(gain))
        if gain[j] <= 0:
            break
        chosen.append(j)
        left = left * (~C[:, j])
    return np.array(chosen, dtype=np.int64)


@dataclass
class SAResult:
    selected: NDArray[np.int64]
    loss_pct: float  # eq. 3 cost × 100, relative to the area of the whole set A
    iterations: int
    accepted: int


def simulated_annealing(
    C: NDArray[np.bool_],
    area: NDArray[np.float64],
    greedy: NDArray[np.int64],
    reduction_pct: float,
    rng: np.random.Generator,
    iterations: int = 4000,
    t0: float = 0.01,
    gamma: float | None = None,
    n_swap0: int = 3,
) -> SAResult:
    """Shrink the Greedy Area set by ``reduction_pct`` % with the least visible-area loss.

    Paper eq. 3–5: cost(B) = 1 − Area(B)/Area(A); a worse B_k is accepted with probability
    e^{−δ/T_k}; n_swap and T decay as e^{−γk}. Moves swap ``n_swap,k`` members of the current
    set with unused viewpoints of A (all reachable ones, not only the greedy ones). Instead of
    a random start (the paper's), B starts from the greedy set minus the viewpoints whose
    unique area is smallest, removed one at a time with coverage counts updated ("repair"),
    so the annealer refines an already good set; a best-improvement 1-swap local search
    finishes it.

    Args:
        C: (m, n) measurability matrix.
        area: (m,) face areas, m².
        greedy: the Greedy Area selection.
        reduction_pct: p_SA, % of the greedy set to remove (0 → greedy returned as is).
        rng: seeded generator.
        iterations: annealing steps.
        t0: initial temperature (cost units: fraction of area).
        gamma: decay rate; default makes T and n_swap fall 1000× over the run.
    """
    A_area = visible_area(C, area, np.arange(C.shape[1]))
    n_target = int(round(len(greedy) * (1.0 - reduction_pct / 100.0)))
    if reduction_pct <= 0 or n_target >= len(greedy) or A_area <= 0:
        loss = 1.0 - visible_area(C, area, greedy) / A_area if A_area > 0 else 0.0
        return SAResult(np.array(greedy, dtype=np.int64), 100.0 * loss, 0, 0)
    n_target = max(1, n_target)
    Ci = C.astype(np.int32)
    count = Ci[:, greedy].sum(axis=1)
    cur = list(int(j) for j in greedy)
    while len(cur) > n_target:  # repair-style start: drop the least unique viewpoint
        unique = np.array([area[(count == 1) & C[:, j]].sum() for j in cur])
        k = int(np.argmin(unique))
        count -= Ci[:, cur[k]]
        cur.pop(k)
    n = C.shape[1]
    in_set = np.zeros(n, dtype=bool)
    in_set[cur] = True

    def cost_of(cnt: NDArray[np.int32]) -> float:
        return 1.0 - float(area[cnt > 0].sum()) / A_area

    cur_cost = cost_of(count)
    best, best_cost = list(cur), cur_cost
    if gamma is None:
        gamma = np.log(1000.0) / max(1, iterations)
    accepted = 0
    k = 0
    for k in range(iterations):
        if best_cost <= 0.0:
            break
        T = t0 * np.exp(-gamma * k)
        n_swap = max(1, int(round(n_swap0 * np.exp(-gamma * k))))
        members = np.flatnonzero(in_set)
        others = np.flatnonzero(~in_set)
        if len(others) == 0:
            break
        n_swap = min(n_swap, len(members), len(others))
        out_j = rng.choice(members, size=n_swap, replace=False)
        in_j = rng.choice(others, size=n_swap, replace=False)
        new_count = count - Ci[:, out_j].sum(axis=1) + Ci[:, in_j].sum(axis=1)
        new_cost = cost_of(new_count)
        delta = new_cost - cur_cost
        if delta <= 0 or rng.random() < np.exp(-delta / max(T, 1e-12)):
            count = new_count
            in_set[out_j] = False
            in_set[in_j] = True
            cur_cost = new_cost
            accepted += 1
            if cur_cost < best_cost - 1e-15:
                best, best_cost = list(np.flatnonzero(in_set)), cur_cost
    best = _swap_polish(C, area, np.array(best, dtype=np.int64))
    best_cost = 1.0 - visible_area(C, area, best) / A_area
    return SAResult(np.array(sorted(best), dtype=np.int64), 100.0 * best_cost, k + 1, accepted)


def _swap_polish(
    C: NDArray[np.bool_], area: NDArray[np.float64], sel: NDArray[np.int64], max_swaps: int = 100
) -> NDArray[np.int64]:
    """Best-improvement 1-swap local search: replace one member by the outsider that adds most.

    Deterministic finish of the annealer (which samples swaps at random): every member's
    removal is evaluated against every outsider in one matrix product per member.
    """
    sel = list(int(j) for j in sel)
    Cf = C.astype(np.float64)
    for _ in range(max_swaps):
        count = C[:, sel].sum(axis=1)
        base = float(area[count > 0].sum())
        outside = np.setdiff1d(np.arange(C.shape[1]), sel)
        if len(outside) == 0:
            break
        best_gain, best_pair = 1e-12, None
        for pos, j in enumerate(sel):
            cnt = count - C[:, j]
            uncovered = area * (cnt == 0)
            lost = float(uncovered[C[:, j]].sum())
            gains = uncovered @ Cf[:, outside] - lost
            k = int(np.argmax(gains))
            if gains[k] > best_gain * base:
                best_gain, best_pair = gains[k] / base, (pos, int(outside[k]))
        if best_pair is None:
            break
        sel[best_pair[0]] = best_pair[1]
    return np.array(sel, dtype=np.int64)


def min_set_cover(C: NDArray[np.bool_], time_limit_s: float = 10.0) -> tuple[int | None, bool, float]:
    """Exact minimum number of viewpoints covering every coverable face (scipy milp/HiGHS).

    Identical rows are merged first. Returns ``(count, proven_optimal, seconds)``; ``count``
    is None when HiGHS found no feasible cover within the time limit.
    """
    from scipy.optimize import Bounds, LinearConstraint, milp
    from scipy.sparse import csr_matrix

    t = time.perf_counter()
    rows = C[C.any(axis=1)]
    if rows.shape[0] == 0:
        return 0, True, 0.0
    rows = np.unique(rows, axis=0)
    n = rows.shape[1]
    res = milp(
        c=np.ones(n),
        constraints=LinearConstraint(csr_matrix(rows.astype(np.float64)), lb=1.0, ub=np.inf),
        integrality=np.ones(n),
        bounds=Bounds(0, 1),
        options={"time_limit": time_limit_s, "disp": False},
    )
    dt = time.perf_counter() - t
    if res.x is None:
        return None, False, dt
    return int(round(res.x.sum())), bool(res.status == 0), dt
