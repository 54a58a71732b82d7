"""Rigid transforms as 4×4 homogeneous matrices.

Naming: ``T_a_b`` maps points expressed in frame ``b`` into frame ``a``
(``p_a = T_a_b @ p_b``), so ``T_a_c = T_a_b @ T_b_c``. Quaternions are ``xyzw``.
Units are metres and radians.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.errors import CellError

__all__ = [
    "Pose",
    "check_transform",
    "invert",
    "look_at",
    "matrix_from_quaternion",
    "pose_error",
    "quaternion_from_matrix",
    "rotation_about",
    "transform_from",
    "transform_from_pose",
    "transform_from_xyz_rpy",
    "pose_from_transform",
]

Pose = tuple[tuple[float, float, float], tuple[float, float, float, float]]
"""A pose as ``((x, y, z), (qx, qy, qz, qw))``."""


def check_transform(T: ArrayLike, name: str = "transform") -> NDArray[np.float64]:
    """Return ``T`` as a float64 (4, 4) rigid transform or raise naming what is wrong.

    Raises:
        CellError: wrong shape, non-finite values, or a rotation part that is not orthonormal.
    """
    A = np.asarray(T, dtype=np.float64)
    if A.shape != (4, 4):
        raise CellError(f"{name} must have shape (4, 4), got {A.shape}")
    if not np.all(np.isfinite(A)):
        raise CellError(f"{name} has non-finite entries: {A.tolist()}")
    R = A[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise CellError(f"{name} rotation part is not a proper rotation: {R.tolist()}")
    if not np.allclose(A[3], [0, 0, 0, 1], atol=1e-9):
        raise CellError(f"{name} last row must be [0, 0, 0, 1], got {A[3].tolist()}")
    return A


def transform_from(R: ArrayLike, p: ArrayLike) -> NDArray[np.float64]:
    """Build a transform from a rotation matrix (3, 3) and a translation (3,)."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, dtype=np.float64)
    T[:3, 3] = np.asarray(p, dtype=np.float64)
    return T


def invert(T: ArrayLike) -> NDArray[np.float64]:
    """Inverse of a rigid transform (uses the rotation's transpose, not a general inverse)."""
    A = np.asarray(T, dtype=np.float64)
    R = A[:3, :3]
    return transform_from(R.T, -R.T @ A[:3, 3])


def matrix_from_quaternion(q: Sequence[float]) -> NDArray[np.float64]:
    """Rotation matrix from a quaternion ``(x, y, z, w)``; the quaternion is normalised first."""
    x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def quaternion_from_matrix(R: ArrayLike) -> NDArray[np.float64]:
    """Quaternion ``(x, y, z, w)`` with ``w >= 0`` from a rotation matrix (Shepperd's method)."""
    M = np.asarray(R, dtype=np.float64)[:3, :3]
    tr = np.trace(M)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [(M[2, 1] - M[1, 2]) / s, (M[0, 2] - M[2, 0]) / s, (M[1, 0] - M[0, 1]) / s, 0.25 * s]
    elif M[0, 0] > M[1, 1] and M[0, 0] > M[2, 2]:
        s = 2.0 * np.sqrt(1.0 + M[0, 0] - M[1, 1] - M[2, 2])
        q = [0.25 * s, (M[0, 1] + M[1, 0]) / s, (M[0, 2] + M[2, 0]) / s, (M[2, 1] - M[1, 2]) / s]
    elif M[1, 1] > M[2, 2]:
        s = 2.0 * np.sqrt(1.0 + M[1, 1] - M[0, 0] - M[2, 2])
        q = [(M[0, 1] + M[1, 0]) / s, 0.25 * s, (M[1, 2] + M[2, 1]) / s, (M[0, 2] - M[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + M[2, 2] - M[0, 0] - M[1, 1])
        q = [(M[0, 2] + M[2, 0]) / s, (M[1, 2] + M[2, 1]) / s, 0.25 * s, (M[1, 0] - M[0, 1]) / s]
    qa = np.asarray(q)
    qa /= np.linalg.norm(qa)
    return -qa if qa[3] < 0 else qa


def transform_from_pose(pose: Pose | Sequence[Sequence[float]]) -> NDArray[np.float64]:
    """Transform from ``((x, y, z), (qx, qy, qz, qw))``."""
    p, q = pose
    return transform_from(matrix_from_quaternion(q), p)


def pose_from_transform(T: ArrayLike) -> Pose:
    """``((x, y, z), (qx, qy, qz, qw))`` of a transform, as plain floats (JSON-ready)."""
    A = np.asarray(T, dtype=np.float64)
    p = A[:3, 3]
    q = quaternion_from_matrix(A[:3, :3])
    return (float(p[0]), float(p[1]), float(p[2])), (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def rotation_about(axis: Sequence[float], angle: float) -> NDArray[np.float64]:
    """Rotation matrix of ``angle`` radians about ``axis`` (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)


def transform_from_xyz_rpy(xyz: Sequence[float], rpy: Sequence[float]) -> NDArray[np.float64]:
    """Transform from a translation and fixed-axis roll, pitch, yaw (``R = Rz(y) Ry(p) Rx(r)``)."""
    r, p, y = rpy
    R = rotation_about((0, 0, 1), y) @ rotation_about((0, 1, 0), p) @ rotation_about((1, 0, 0), r)
    return transform_from(R, xyz)


def pose_error(T_a: ArrayLike, T_b: ArrayLike) -> tuple[float, float]:
    """Translation (m) and rotation (rad) distance between two transforms of the same frame."""
    A = np.asarray(T_a, dtype=np.float64)
    B = np.asarray(T_b, dtype=np.float64)
    dt = float(np.linalg.norm(A[:3, 3] - B[:3, 3]))
    R = A[:3, :3].T @ B[:3, :3]
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    return dt, float(np.arccos(c))


_LOOK_AT_PARALLEL = 1e-6
"""|sin| of the eye→target/up angle below which ``up`` gives no image x axis."""


def look_at(
    eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0), *, roll_rad: float = 0.0
) -> NDArray[np.float64]:
    """Camera optical frame (+Z toward ``target``, +X right, +Y down in the image) at ``eye``.

    The image's "up" (−Y) leans toward ``up``: ``x = z × up``, ``y = z × x``. The result is
    then rolled by ``roll_rad`` about the optical axis (positive turns the image x axis toward
    its y axis).

    Degenerate case: when eye→target is parallel (or anti-parallel) to ``up`` (|sin| of the
    angle below 1e-6), ``up`` says nothing about the image's orientation, and world +Y takes
    its place (world +X if the view also runs along Y). Looking straight down with the default
    ``up`` therefore gives image x = world +X, image y = world −Y: a map seen from above.

    Args:
        eye: (3,) camera position.
        target: (3,) the point the optical axis passes through.
        up: (3,) world direction the image's top should lean toward (need not be unit).
        roll_rad: rotation about the optical axis, applied last.

    Returns:
        (4, 4) ``T_world_cam``.

    Raises:
        CellError: ``eye`` equals ``target``, ``up`` is zero, or a value is not finite.
    """
    e, t, u = (np.asarray(v, dtype=np.float64).reshape(3) for v in (eye, target, up))
    if not (np.isfinite(e).all() and np.isfinite(t).all() and np.isfinite(u).all()):
        raise CellError(f"look_at needs finite points, got eye={e.tolist()} target={t.tolist()} up={u.tolist()}")
    z = t - e
    dz, du = float(np.linalg.norm(z)), float(np.linalg.norm(u))
    if dz < 1e-12:
        raise CellError(f"look_at: eye {e.tolist()} and target {t.tolist()} coincide; no view direction")
    if du < 1e-12:
        raise CellError(f"look_at: up {u.tolist()} is the zero vector")
    z /= dz
    x = np.cross(z, u / du)
    if np.linalg.norm(x) < _LOOK_AT_PARALLEL:
        helper = (0.0, 1.0, 0.0) if abs(z[1]) < 0.9 else (1.0, 0.0, 0.0)
        x = np.cross(z, helper)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.column_stack([x, y, z])
    if roll_rad:
        R = R @ rotation_about((0.0, 0.0, 1.0), roll_rad)
    return transform_from(R, e)
