"""Viewpoint poses from seed points (paper eq. 1–2).

External: the optical axis z_i = k_i = −n_i (looking into the seed face), origins at distances
d_0 … d_{D−1} from the seed, in preference order. Internal: k_i points from the top-opening
origin O to the seed; origins again at d_j from the seed along −k_i.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import PlanningError

__all__ = ["Viewpoints", "concat", "generate_viewpoints", "opening_viewpoints", "rotation_z_to"]


class Viewpoints:
    """A batch of candidate camera poses in the bin frame.

    Attributes:
        T: (M, 4, 4) ``T_bin_cam`` (optical frame: +Z forward).
        seed: (M,) index of the seed (= the direction) each viewpoint belongs to.
        rank: (M,) preference rank j of its distance d_j (0 = preferred).
        seed_face: (M,) the seed face id.
        seed_point: (M, 3) the seed point, m.
    """

    def __init__(self, T, seed, rank, seed_face, seed_point) -> None:
        self.T = np.asarray(T, dtype=np.float64)
        self.seed = np.asarray(seed, dtype=np.int64)
        self.rank = np.asarray(rank, dtype=np.int64)
        self.seed_face = np.asarray(seed_face, dtype=np.int64)
        self.seed_point = np.asarray(seed_point, dtype=np.float64)

    def __len__(self) -> int:
        return len(self.seed)

    def subset(self, idx: NDArray) -> Viewpoints:
        return Viewpoints(self.T[idx], self.seed[idx], self.rank[idx], self.seed_face[idx], self.seed_point[idx])


def rotation_z_to(k: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotations (N, 3, 3) taking +Z onto the unit vectors ``k`` (N, 3) — paper eq. 1.

    R = I + [v]× + [v]×² / (1 + Z·k), v = Z × k. At k = −Z (1 + Z·k = 0) eq. 1 is singular;
    there a half turn about X is used.
    """
    K = np.asarray(k, dtype=np.float64).reshape(-1, 3)
    K = K / np.linalg.norm(K, axis=1, keepdims=True)
    v = np.cross(np.array([0.0, 0.0, 1.0]), K)
    c = K[:, 2]
    S = np.zeros((len(K), 3, 3))
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 0] = -v[:, 2], v[:, 1], v[:, 2]
    S[:, 1, 2], S[:, 2, 0], S[:, 2, 1] = -v[:, 0], -v[:, 1], v[:, 0]
    R = np.broadcast_to(np.eye(3), S.shape).copy()
    ok = c > -1.0 + 1e-9
    R[ok] += S[ok] + (S[ok] @ S[ok]) / (1.0 + c[ok])[:, None, None]
    R[~ok] = np.diag([1.0, -1.0, -1.0])
    return R


def generate_viewpoints(
    points: NDArray[np.float64],
    normals: NDArray[np.float64],
    seed_faces: NDArray[np.int64],
    surface: str,
    distances: tuple[float, ...],
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> Viewpoints:
    """All D viewpoints of every seed, ordered seed-major then by preference rank.

    Args:
        points: (N, 3) seed points, m.
        normals: (N, 3) seed-face outward normals.
        seed_faces: (N,) seed-face ids.
        surface: "external" or "internal".
        distances: d_0 … d_{D−1}, m, in order of preference.
        origin: the internal viewpoints' radiating point O, m (bin frame).
    """
    d = np.asarray(distances, dtype=np.float64)
    if d.ndim != 1 or len(d) == 0 or np.any(d <= 0):
        raise PlanningError(f"viewpoint distances {list(distances)} must be a non-empty list of positive metres")
    P = np.asarray(points, dtype=np.float64)
    if surface == "external":
        k = -np.asarray(normals, dtype=np.float64)
    elif surface == "internal":
        k = P - np.asarray(origin, dtype=np.float64)
        bad = np.linalg.norm(k, axis=1) < 1e-6
        k[bad] = -np.asarray(normals, dtype=np.float64)[bad]
    else:
        raise PlanningError(f"surface {surface!r} is unknown; expected 'external' or 'internal'")
    k = k / np.linalg.norm(k, axis=1, keepdims=True)
    R = rotation_z_to(k)
    n, D = len(P), len(d)
    T = np.zeros((n, D, 4, 4))
    T[:, :, :3, :3] = R[:, None]
    T[:, :, :3, 3] = P[:, None, :] - d[None, :, None] * k[:, None, :]  # eq. 2
    T[:, :, 3, 3] = 1.0
    seed = np.repeat(np.arange(n), D)
    rank = np.tile(np.arange(D), n)
    return Viewpoints(T.reshape(-1, 4, 4), seed, rank, np.asarray(seed_faces)[seed], P[seed])


OPENING_ANCHORS_M = (0.10, 0.0, -0.15)
"""Heights above the top-opening centre (bin frame z) the opening views look from: above the
opening (the wrist stays out of it), in its plane, and just inside it (the camera dips in)."""
OPENING_FAR_MARGIN_M = 0.05
"""An opening view stays this far inside the camera's far depth of view."""


def opening_viewpoints(
    points: NDArray[np.float64],
    seed_faces: NDArray[np.int64],
    dov: tuple[float, float],
    first_rank: int,
    anchors: tuple[float, ...] = OPENING_ANCHORS_M,
) -> Viewpoints:
    """Internal viewpoints that look at each seed *through the top opening* (ranks ``first_rank`` …).

    The fixed distances of :func:`generate_viewpoints` put the camera 0.3–0.4 m from the seed on
    the ray from the opening: for a deep cavity behind a narrow opening that is inside the bin, where
    no arm reaches (issue 35: a narrow-opening hopper, 4 of 422 internal viewpoints reachable from any
    station). Here, per anchor A on the opening's axis (``anchors`` m above its centre, the bin-frame
    origin), the camera looks from A at the seed P: at A itself when P lies within the depth of view
    (less :data:`OPENING_FAR_MARGIN_M`), else as far back towards A as the depth of view allows. The
    arm then reaches in along the line of sight, the wrist behind the camera, through the opening.

    Args:
        points: (N, 3) internal seed points, m (bin frame).
        seed_faces: (N,) their faces.
        dov: the camera's (near, far) depth of view, m.
        first_rank: the rank of the first anchor's views (after the fixed distances' ranks).
        anchors: heights of the anchors above the opening centre, m, in preference order.
    """
    P = np.asarray(points, dtype=np.float64)
    near, far = float(dov[0]), float(dov[1]) - OPENING_FAR_MARGIN_M
    if far <= near:
        raise PlanningError(f"camera depth of view {list(dov)} leaves no room for opening views (far − near ≤ 0.05 m)")
    n, D = len(P), len(anchors)
    A = np.zeros((D, 3))
    A[:, 2] = anchors
    v = P[:, None, :] - A[None]  # (n, D, 3) anchor → seed
    dist = np.linalg.norm(v, axis=2)
    dist = np.maximum(dist, 1e-6)
    k = v / dist[..., None]
    d = np.clip(dist, near + 0.05, far)
    T = np.zeros((n, D, 4, 4))
    T[:, :, :3, :3] = rotation_z_to(k.reshape(-1, 3)).reshape(n, D, 3, 3)
    T[:, :, :3, 3] = P[:, None, :] - d[..., None] * k
    T[:, :, 3, 3] = 1.0
    seed = np.repeat(np.arange(n), D)
    rank = first_rank + np.tile(np.arange(D), n)
    return Viewpoints(T.reshape(-1, 4, 4), seed, rank, np.asarray(seed_faces)[seed], P[seed])


def concat(a: Viewpoints, b: Viewpoints) -> Viewpoints:
    """Both batches as one (``b`` after ``a``; seeds index the same seed list)."""
    return Viewpoints(
        np.concatenate([a.T, b.T]),
        np.concatenate([a.seed, b.seed]),
        np.concatenate([a.rank, b.rank]),
        np.concatenate([a.seed_face, b.seed_face]),
        np.concatenate([a.seed_point, b.seed_point]),
    )
