"""Seed points: p_SP % of a surface's face count, spread uniformly over that surface."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import PlanningError
from cellctl.geometry.catalog import BinMesh

__all__ = ["sample_seeds"]


def sample_seeds(
    mesh: BinMesh, surface: str, seed_pct: float, rng: np.random.Generator, oversample: int = 6
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Sample seed points and their seed faces.

    N = round(p_SP/100 · faces of the surface). Points are drawn area-weighted (``oversample``·N
    candidates), then thinned by farthest-point sampling, which keeps the paper's "uniformly
    distributed" subset of a dense point cloud without clumps. Each seed's face is the face it
    was drawn on (its closest face).

    Args:
        mesh: the bin mesh.
        surface: "external" or "internal".
        seed_pct: p_SP in (0, 100].
        rng: seeded generator.

    Returns:
        ``(points (N, 3) m, seed_faces (N,))``.

    Raises:
        PlanningError: p_SP outside (0, 100] or the surface has no faces.
    """
    if not (0.0 < float(seed_pct) <= 100.0):
        raise PlanningError(f"seed percentage {seed_pct!r} must be in (0, 100]")
    mask = mesh.surface_mask(surface)
    faces = np.flatnonzero(mask)
    if len(faces) == 0:
        raise PlanningError(f"mesh {mesh.name!r} has no {surface} faces to seed")
    n = max(1, int(round(seed_pct / 100.0 * len(faces))))
    w = mesh.areas[faces] / mesh.areas[faces].sum()
    m = min(len(faces) * 4, n * oversample) if n < len(faces) else n
    cand_f = faces[rng.choice(len(faces), size=m, p=w)]
    tri = mesh.vertices[mesh.faces[cand_f]]
    u, v = rng.random(m), rng.random(m)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    pts = tri[:, 0] + (tri[:, 1] - tri[:, 0]) * u[:, None] + (tri[:, 2] - tri[:, 0]) * v[:, None]
    if m == n:
        return pts, cand_f
    chosen = _farthest_points(pts, n, rng)
    return pts[chosen], cand_f[chosen]


def _farthest_points(P: NDArray[np.float64], n: int, rng: np.random.Generator) -> NDArray[np.int64]:
    out = np.empty(n, dtype=np.int64)
    out[0] = rng.integers(len(P))
    d = np.linalg.norm(P - P[out[0]], axis=1)
    for i in range(1, n):
        out[i] = int(np.argmax(d))
        d = np.minimum(d, np.linalg.norm(P - P[out[i]], axis=1))
    return out
