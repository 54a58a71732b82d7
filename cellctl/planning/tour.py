"""Visiting order: MAX-MIN Ant System over the path-cost matrix, then 2-opt (paper §IV-A3).

The tour is an open path that starts at node 0 (the robot's current configuration) and
visits every other node once; it does not return.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["ant_colony", "path_cost", "two_opt"]


def path_cost(D: NDArray[np.float64], order: NDArray[np.int64] | list[int]) -> float:
    """Total cost of visiting ``order`` (node sequence) under cost matrix ``D``."""
    o = np.asarray(order)
    return float(D[o[:-1], o[1:]].sum()) if len(o) > 1 else 0.0


def _nearest_neighbour(D: NDArray[np.float64]) -> list[int]:
    n = len(D)
    order, left = [0], set(range(1, n))
    while left:
        i = order[-1]
        j = min(left, key=lambda k: (D[i, k], k))
        order.append(j)
        left.remove(j)
    return order


def ant_colony(
    D: NDArray[np.float64],
    rng: np.random.Generator,
    n_ants: int | None = None,
    iterations: int = 150,
    alpha: float = 1.0,
    beta: float = 2.0,
    rho: float = 0.05,
    stagnation: int = 50,
) -> NDArray[np.int64]:
    """MAX-MIN Ant System for an open path from node 0 (notes §3 parameters).

    η = 1/(d + 0.1), τ_max = 1/(ρ·C_NN), τ_min = τ_max/(2n); only the best ant deposits;
    pheromones reset after ``stagnation`` iterations without improvement.

    Returns:
        Node order starting with 0.
    """
    n = len(D)
    if n <= 2:
        return np.arange(n)
    n_ants = n_ants or max(10, n)
    eta = 1.0 / (D + 0.1)
    best = _nearest_neighbour(D)
    best_cost = path_cost(D, best)
    tau_max = 1.0 / (rho * max(best_cost, 1e-9))
    tau_min = tau_max / (2 * n)
    tau = np.full((n, n), tau_max)
    since = 0
    for _ in range(iterations):
        weights = (tau**alpha) * (eta**beta)
        # all ants step together: one row of transition weights per ant
        orders = np.zeros((n_ants, n), dtype=np.int64)
        visited = np.zeros((n_ants, n), dtype=bool)
        visited[:, 0] = True
        rows = np.arange(n_ants)
        for s in range(1, n):
            w = weights[orders[:, s - 1]] * ~visited
            cum = np.cumsum(w, axis=1)
            r = rng.random(n_ants) * cum[:, -1]
            j = np.minimum((cum <= r[:, None]).sum(axis=1), n - 1)
            stuck = visited[rows, j]  # only when all weights underflow: take the first free node
            if np.any(stuck):
                j[stuck] = np.argmax(~visited[stuck], axis=1)
            orders[:, s] = j
            visited[rows, j] = True
        costs = D[orders[:, :-1], orders[:, 1:]].sum(axis=1)
        a_best = int(np.argmin(costs))
        it_best, it_cost = list(orders[a_best]), float(costs[a_best])
        if it_cost < best_cost - 1e-12:
            best, best_cost, since = it_best, it_cost, 0
            tau_max = 1.0 / (rho * best_cost)
            tau_min = tau_max / (2 * n)
        else:
            since += 1
        tau *= 1.0 - rho
        o = np.asarray(best)
        tau[o[:-1], o[1:]] += 1.0 / max(best_cost, 1e-9)
        np.clip(tau, tau_min, tau_max, out=tau)
        if since >= stagnation:
            tau[:] = tau_max
            since = 0
    return np.asarray(best, dtype=np.int64)


def two_opt(D: NDArray[np.float64], order: NDArray[np.int64]) -> NDArray[np.int64]:
    """2-opt on an open path with a fixed start: reverse segments while that lowers the cost.

    Works for asymmetric ``D`` too (the reversed segment's internal cost is recomputed).
    """
    o = list(int(x) for x in order)
    n = len(o)
    improved = True
    while improved:
        improved = False
        for i in range(1, n - 1):
            for k in range(i + 1, n):
                seg = o[i : k + 1]
                before = D[o[i - 1], o[i]] + (D[o[k], o[k + 1]] if k + 1 < n else 0.0)
                after = D[o[i - 1], o[k]] + (D[o[i], o[k + 1]] if k + 1 < n else 0.0)
                inner_old = sum(D[seg[t], seg[t + 1]] for t in range(len(seg) - 1))
                inner_new = sum(D[seg[t + 1], seg[t]] for t in range(len(seg) - 1))
                if after + inner_new < before + inner_old - 1e-12:
                    o[i : k + 1] = seg[::-1]
                    improved = True
    return np.asarray(o, dtype=np.int64)
