"""Viewpoint filters in increasing cost (paper §IV-A1a): height, distance, occlusion, camera body.

Each returns a boolean keep-mask over the viewpoints it is given.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.catalog import BinMesh
from cellctl.planning.collision import PlanningWorld
from cellctl.planning.raycast import RayCaster
from cellctl.planning.viewpoints import Viewpoints

__all__ = ["camera_collision_filter", "distance_filter", "height_filter", "occlusion_filter"]


def height_filter(vp: Viewpoints, mesh: BinMesh, camera_max_dim: float) -> NDArray[np.bool_]:
    """Keep origins above the mesh's lowest point minus the camera's largest dimension (paper)."""
    z_min = float(mesh.vertices[:, 2].min()) - camera_max_dim
    return vp.T[:, 2, 3] >= z_min


def distance_filter(vp: Viewpoints, p_base: NDArray[np.float64], max_reach: float) -> NDArray[np.bool_]:
    """Keep origins within ``max_reach`` (m) of the robot base origin (bin frame)."""
    return np.linalg.norm(vp.T[:, :3, 3] - np.asarray(p_base)[None], axis=1) <= max_reach


def occlusion_filter(vp: Viewpoints, mesh: BinMesh, rays: RayCaster) -> NDArray[np.bool_]:
    """Keep viewpoints whose ray to their seed-face centroid hits no other triangle first."""
    o = vp.T[:, :3, 3]
    c = mesh.centroids[vp.seed_face]
    v = c - o
    dist = np.linalg.norm(v, axis=1)
    return rays.first_hit_is(o, v / dist[:, None], vp.seed_face, dist)


def camera_collision_filter(vp: Viewpoints, world: PlanningWorld) -> NDArray[np.bool_]:
    """Keep viewpoints where the camera body (and its mount) clears the bin and the floor."""
    return world.camera_free(vp.T)
