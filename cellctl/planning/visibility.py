"""Visible faces per viewpoint → measurability matrix (paper §IV-A1c, §IV-A2).

A face is properly visible from a viewpoint when its centroid projects inside the image
(pinhole intrinsics of :class:`cellctl.geometry.camera.CameraModel`), its distance lies in
the depth-of-view range, the view ray meets the
face at no more than the maximum glance angle from its normal, and the ray from the camera
to the centroid hits that face first (occlusion, one embree query for all pairs).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.camera import CameraModel
from cellctl.geometry.catalog import BinMesh
from cellctl.planning.raycast import RayCaster

__all__ = ["measurability"]


def measurability(
    T_bin_cam: NDArray[np.float64],
    mesh: BinMesh,
    faces: NDArray[np.int64],
    cam: CameraModel,
    rays: RayCaster,
    progress: Callable[[int, int], None] | None = None,
) -> NDArray[np.bool_]:
    """Measurability matrix C (m × n): C[i, j] = face ``faces[i]`` properly visible from viewpoint j.

    Args:
        T_bin_cam: (n, 4, 4) viewpoint poses, bin frame.
        mesh: bin mesh.
        faces: (m,) the face ids that matter (the planned surface).
        cam: camera model.
        rays: ray caster on the same mesh.
    """
    n = len(T_bin_cam)
    C = np.zeros((len(faces), n), dtype=bool)
    if n == 0 or len(faces) == 0:
        return C
    c = mesh.centroids[faces]
    nrm = mesh.normals[faces]
    cos_max = np.cos(np.deg2rad(cam.max_glance_deg))
    pairs_v, pairs_f, origins, dirs, dists = [], [], [], [], []
    for j in range(n):
        R, t = T_bin_cam[j, :3, :3], T_bin_cam[j, :3, 3]
        v = c - t
        d = np.linalg.norm(v, axis=1)
        p = v @ R  # camera-frame coordinates (R^T v)
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = cam.fx * p[:, 0] / z + cam.cx
            w = cam.fy * p[:, 1] / z + cam.cy
        ok = (z > 1e-6) & (u >= 0) & (u <= cam.width) & (w >= 0) & (w <= cam.height)
        ok &= (d >= cam.dov[0]) & (d <= cam.dov[1])
        ok &= -np.einsum("ij,ij->i", nrm, v) >= cos_max * d  # cos(angle(n, t − c)) ≥ cos α_max
        sel = np.flatnonzero(ok)
        pairs_v.append(np.full(len(sel), j))
        pairs_f.append(sel)
        origins.append(np.repeat(t[None], len(sel), axis=0))
        dirs.append(v[sel] / d[sel, None])
        dists.append(d[sel])
        if progress and (j % 16 == 0):
            progress(j, n)
    pv, pf = np.concatenate(pairs_v), np.concatenate(pairs_f)
    if len(pv):
        seen = rays.first_hit_is(np.concatenate(origins), np.concatenate(dirs), faces[pf], np.concatenate(dists))
        C[pf[seen], pv[seen]] = True
    if progress:
        progress(n, n)
    return C
