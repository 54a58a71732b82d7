"""First-hit ray casting on a triangle mesh (embree through trimesh/embreex, numpy fallback).

Embree trades precision (trimesh#1919): a ray aimed at a face centroid may report the
neighbouring face across an edge. A target counts as seen when the first hit is the target
face or lies no nearer than the target distance minus ``eps``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["RayCaster"]


class RayCaster:
    """First-hit queries on a fixed mesh.

    Args:
        vertices: (V, 3) m.
        faces: (F, 3) indices.
    """

    def __init__(self, vertices: ArrayLike, faces: ArrayLike) -> None:
        import trimesh

        self.mesh = trimesh.Trimesh(np.asarray(vertices), np.asarray(faces), process=False)
        try:
            from trimesh.ray.ray_pyembree import RayMeshIntersector

            self._ray = RayMeshIntersector(self.mesh)
            self.engine = "embree"
        except ImportError:  # embreex missing: correct but ~100x slower
            from trimesh.ray.ray_triangle import RayMeshIntersector as NumpyIntersector

            self._ray = NumpyIntersector(self.mesh)
            self.engine = "numpy"

    def first_hit(self, origins: ArrayLike, directions: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Face index (−1: none) and distance (inf: none) of the first hit of each ray."""
        Org = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        D = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        face = np.full(len(Org), -1, dtype=np.int64)
        dist = np.full(len(Org), np.inf)
        if len(Org) == 0:
            return face, dist
        locs, ray_idx, tri_idx = self._ray.intersects_location(Org, D, multiple_hits=False)
        if len(ray_idx):
            d = np.einsum("ij,ij->i", locs - Org[ray_idx], D[ray_idx])
            face[ray_idx] = tri_idx
            dist[ray_idx] = d
        return face, dist

    def first_hit_is(
        self,
        origins: ArrayLike,
        directions: ArrayLike,
        target: ArrayLike,
        target_dist: ArrayLike,
        eps: float = 2e-3,
    ) -> NDArray[np.bool_]:
        """True where the ray reaches face ``target`` at ``target_dist`` before anything else."""
        face, dist = self.first_hit(origins, directions)
        tgt = np.asarray(target)
        td = np.asarray(target_dist, dtype=np.float64)
        return (face == tgt) | (dist >= td - eps)
