"""What to wash: target faces from a cycle's dirt map, dilated by a margin, split into regions and facets.

A dirt map with ``face_p`` (the detector's fused per-face probabilities,
:mod:`cellctl.classify.heatmap`) gives the faces at or above the wash threshold; an older map
(``seen_dirty`` face ids only) gives those faces. Faces no view saw are not washed: nothing says
they are dirty (the verdict names them as unseen instead).

Regions are the connected pieces of the dilated target set on one surface; a region is cut
into **facets** (faces whose normals lie within :data:`FACET_DEG` of the facet's first face) so
a raster sweep runs over a near-planar patch and the jet stays perpendicular to it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.catalog import BinMesh

__all__ = ["FACET_DEG", "Facet", "dirty_from_map", "facets_of", "dilate", "face_adjacency"]

FACET_DEG = 25.0
"""Largest normal spread within one raster facet."""


def dirty_from_map(dirt_map: dict[str, Any], n_faces: int, threshold: float) -> tuple[NDArray[np.bool_], str]:
    """Faces the dirt map calls dirty, and where that came from (``"face_p"`` or ``"seen_dirty"``).

    Raises:
        ClassifierError: ``face_p`` present but malformed or of another mesh.
        PlanningError: a ``seen_dirty`` id outside the mesh.
    """
    from cellctl.classify.heatmap import face_probabilities
    from cellctl.errors import PlanningError

    p = face_probabilities(dirt_map, n_faces)
    if p is not None:
        return np.nan_to_num(p, nan=0.0) >= threshold, "face_p"
    ids = np.asarray(dirt_map.get("seen_dirty", []), dtype=np.int64)
    if ids.size and (ids.min() < 0 or ids.max() >= n_faces):
        raise PlanningError(f"dirt map seen_dirty id {int(ids.max())} is outside the mesh's {n_faces} faces")
    out = np.zeros(n_faces, bool)
    out[ids] = True
    return out, "seen_dirty"


def face_adjacency(mesh: BinMesh) -> list[NDArray[np.int64]]:
    """Per face, the faces sharing a vertex position with it (welded by position: meshes may
    repeat vertices along sharp edges)."""
    key = np.round(mesh.vertices / 1e-5).astype(np.int64)
    _, weld = np.unique(key, axis=0, return_inverse=True)
    fv = weld.reshape(-1)[mesh.faces]
    n_v = int(fv.max()) + 1
    order = np.argsort(fv.reshape(-1), kind="stable")
    owner = np.repeat(np.arange(len(fv)), 3)[order]
    starts = np.searchsorted(fv.reshape(-1)[order], np.arange(n_v + 1))
    vert_faces = [owner[starts[v] : starts[v + 1]] for v in range(n_v)]
    return [np.unique(np.concatenate([vert_faces[v] for v in tri])) for tri in fv]


def dilate(mesh: BinMesh, faces: NDArray[np.bool_], margin_m: float) -> NDArray[np.bool_]:
    """``faces`` plus every face of the same surface, facing within 90° of one of them, whose
    centroid lies within ``margin_m`` of one of them (of its centroid or a corner: the powder
    runs past a triangle's edge, not to the middle of its neighbour)."""
    out = faces.copy()
    if margin_m <= 0 or not faces.any():
        return out
    from scipy.spatial import cKDTree

    src = np.flatnonzero(faces)
    tri = mesh.vertices[mesh.faces[src]]
    tree = cKDTree(np.concatenate([mesh.centroids[src, None], tri], axis=1).reshape(-1, 3))
    owner = np.repeat(src, 4)
    near = tree.query_ball_point(mesh.centroids, r=margin_m)
    for f, js in enumerate(near):
        if out[f] or not js:
            continue
        s = owner[np.asarray(js)]
        same = (mesh.surface[s] == mesh.surface[f]) & (mesh.normals[s] @ mesh.normals[f] > 0)
        out[f] = bool(same.any())
    return out


@dataclass(frozen=True)
class Facet:
    """A near-planar piece of one target region.

    Attributes:
        region: the region's id (connected target faces of one surface).
        surface: the surface tag (:data:`cellctl.surface.EXTERNAL` / ``INTERNAL``).
        faces: the facet's face ids.
        normal: area-weighted unit normal (outward for the surface).
    """

    region: int
    surface: int
    faces: NDArray[np.int64]
    normal: NDArray[np.float64]


def facets_of(mesh: BinMesh, targets: NDArray[np.bool_], adj: list[NDArray[np.int64]]) -> list[Facet]:
    """Connected regions of ``targets`` (per surface), each cut into facets by normal."""
    cos_facet = np.cos(np.deg2rad(FACET_DEG))
    region = np.full(mesh.n_faces, -1)
    n_regions = 0
    for f0 in np.flatnonzero(targets):
        if region[f0] >= 0:
            continue
        stack = [int(f0)]
        region[f0] = n_regions
        while stack:
            f = stack.pop()
            for g in adj[f]:
                if targets[g] and region[g] < 0 and mesh.surface[g] == mesh.surface[f0]:
                    region[g] = n_regions
                    stack.append(int(g))
        n_regions += 1
    facet = np.full(mesh.n_faces, -1)
    out: list[Facet] = []
    # largest faces seed facets first: their normal is the facet's most representative one
    for f0 in sorted(np.flatnonzero(targets), key=lambda f: -mesh.areas[f]):
        if facet[f0] >= 0:
            continue
        n0 = mesh.normals[f0]
        members, stack = [int(f0)], [int(f0)]
        facet[f0] = len(out)
        while stack:
            f = stack.pop()
            for g in adj[f]:
                if region[g] == region[f0] and facet[g] < 0 and mesh.normals[g] @ n0 >= cos_facet:
                    facet[g] = len(out)
                    members.append(int(g))
                    stack.append(int(g))
        ids = np.array(sorted(members), dtype=np.int64)
        nrm = (mesh.normals[ids] * mesh.areas[ids, None]).sum(axis=0)
        out.append(Facet(int(region[f0]), int(mesh.surface[f0]), ids, nrm / max(np.linalg.norm(nrm), 1e-12)))
    return out
