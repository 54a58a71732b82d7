"""Hand–eye calibration (eye-in-hand): solve ``T_flange_cam`` from robot poses and board views.

``cv2.calibrateHandEye`` is missing from opencv-python-headless 5.0.0.93 (opencv#29565), so
this is Park & Martin (IEEE T-RA 10(5), 1994) in numpy.

For views ``i, j`` of a static board, ``T_base_flange_i · X · T_cam_board_i`` is the same
board pose, so with ``A = T_base_flange_j⁻¹ · T_base_flange_i`` (flange motion) and
``B = T_cam_board_j · T_cam_board_i⁻¹`` (camera motion) every pair gives ``A X = X B``.

* Rotation: with ``α = log R_A`` and ``β = log R_B`` (axis·angle vectors), ``α = R_X β``;
  ``R_X`` is the orthogonal Procrustes solution of ``Σ α βᵀ`` (SVD). This equals Park–Martin's
  ``(MᵀM)^-½ Mᵀ`` and stays a proper rotation when noise makes ``M`` ill-conditioned.
* Translation: ``(R_A − I) t_X = R_X t_B − t_A`` stacked over all pairs, least squares.

Needs ≥ 3 views with rotations about ≥ 2 non-parallel axes. Light module (numpy only).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.errors import CellError, ConfigError
from cellctl.geometry.transforms import check_transform, invert, pose_from_transform, transform_from

if TYPE_CHECKING:
    from cellctl.config import CellConfig

__all__ = [
    "MAX_FLANGE_CAM_M",
    "HandEyeResult",
    "configured_hand_eye",
    "load_hand_eye",
    "log_rotation",
    "solve_hand_eye",
]

# A camera further than this from the flange is a wrong file or wrong units (mm), not a mount.
MAX_FLANGE_CAM_M = 0.5


@dataclass(frozen=True)
class HandEyeResult:
    """A hand–eye solution and its consistency.

    Attributes:
        T_flange_cam: 4×4, camera optical frame → flange frame.
        T_base_board: 4×4 board pose in the base frame implied by the solution (mean over views).
        residual_mm: per view, distance of its implied board origin to the mean, mm.
        residual_deg: per view, rotation of its implied board pose to the mean, degrees.
        n_views: views used.
        axis_spread_deg: the largest angle between relative-rotation axes (≈ 90 is ideal;
            near 0 the problem is degenerate).
    """

    T_flange_cam: NDArray[np.float64]
    T_base_board: NDArray[np.float64]
    residual_mm: list[float]
    residual_deg: list[float]
    n_views: int
    axis_spread_deg: float

    def to_dict(self) -> dict[str, Any]:
        p, q = pose_from_transform(self.T_flange_cam)
        return {
            "T_flange_cam": {"position": list(p), "orientation": list(q)},
            "T_flange_cam_matrix": self.T_flange_cam.tolist(),
            "n_views": self.n_views,
            "residual_mm": {"rms": _rms(self.residual_mm), "max": max(self.residual_mm)},
            "residual_deg": {"rms": _rms(self.residual_deg), "max": max(self.residual_deg)},
            "axis_spread_deg": round(self.axis_spread_deg, 2),
        }


def _rms(x: Sequence[float]) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def log_rotation(R: ArrayLike) -> NDArray[np.float64]:
    """Axis·angle vector (3,) of a rotation matrix, angle in radians (0 … π)."""
    M = np.asarray(R, dtype=np.float64)
    c = np.clip((np.trace(M) - 1.0) / 2.0, -1.0, 1.0)
    theta = float(np.arccos(c))
    if theta < 1e-9:
        return np.zeros(3)
    if np.pi - theta < 1e-6:
        # Near π the antisymmetric part vanishes: axis from the symmetric part.
        B = (M + np.eye(3)) / 2.0
        axis = np.sqrt(np.clip(np.diag(B), 0.0, None))
        k = int(np.argmax(axis))
        axis = B[:, k] / np.sqrt(max(B[k, k], 1e-300))
        return axis / np.linalg.norm(axis) * theta
    w = np.array([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]]) / (2.0 * np.sin(theta))
    return w * theta


def solve_hand_eye(T_base_flange: Sequence[ArrayLike], T_cam_board: Sequence[ArrayLike]) -> HandEyeResult:
    """Solve the eye-in-hand calibration ``T_flange_cam`` (Park–Martin).

    Args:
        T_base_flange: per view, the flange pose in the robot base frame (forward kinematics), 4×4.
        T_cam_board: per view, the board pose in the camera optical frame (PnP), 4×4.

    Returns:
        The solution with per-view consistency residuals.

    Raises:
        CellError: fewer than 3 views, mismatched lists, or motions without rotation about two
            independent axes (the problem is then degenerate).
    """
    if len(T_base_flange) != len(T_cam_board):
        raise CellError(
            f"hand-eye needs one board pose per robot pose: got {len(T_base_flange)} robot poses and "
            f"{len(T_cam_board)} board poses"
        )
    n = len(T_base_flange)
    if n < 3:
        raise CellError(f"hand-eye needs at least 3 views, got {n}")
    F = [check_transform(T, f"T_base_flange[{i}]") for i, T in enumerate(T_base_flange)]
    C = [check_transform(T, f"T_cam_board[{i}]") for i, T in enumerate(T_cam_board)]
    alphas, betas, As, Bs = [], [], [], []
    for i in range(n):
        for j in range(i + 1, n):
            A = invert(F[j]) @ F[i]
            B = C[j] @ invert(C[i])
            a = log_rotation(A[:3, :3])
            b = log_rotation(B[:3, :3])
            if np.linalg.norm(a) < np.radians(2.0):
                continue  # almost pure translation: no information on R_X, poor conditioning for t_X
            alphas.append(a)
            betas.append(b)
            As.append(A)
            Bs.append(B)
    if len(alphas) < 2:
        raise CellError(
            f"hand-eye: only {len(alphas)} view pair(s) rotate by ≥ 2°; move the arm through rotations "
            "about at least two different axes"
        )
    al = np.array(alphas)
    axes = al / np.linalg.norm(al, axis=1, keepdims=True)
    spread = float(
        np.degrees(
            max(
                np.arccos(np.clip(abs(axes[i] @ axes[j]), 0.0, 1.0))
                for i in range(len(axes))
                for j in range(i + 1, len(axes))
            )
        )
    )
    if spread < 5.0:
        raise CellError(
            f"hand-eye: all relative rotations share one axis (spread {spread:.1f}° < 5°); "
            "the rotation about "
            "that axis is unobservable — add views rotated about another axis"
        )
    H = np.array(betas).T @ al  # Σ β αᵀ (3×3)
    U, _S, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R_X = Vt.T @ D @ U.T
    M = np.vstack([A[:3, :3] - np.eye(3) for A in As])
    rhs = np.concatenate([R_X @ B[:3, 3] - A[:3, 3] for A, B in zip(As, Bs, strict=True)])
    t_X = np.linalg.lstsq(M, rhs, rcond=None)[0]
    X = transform_from(R_X, t_X)
    # Consistency: every view implies a board pose in the base frame; they should coincide.
    boards = [F[i] @ X @ C[i] for i in range(n)]
    p_mean = np.mean([b[:3, 3] for b in boards], axis=0)
    Mq = np.zeros((4, 4))
    for b in boards:
        q = np.asarray(pose_from_transform(b)[1])
        Mq += np.outer(q, q)
    from cellctl.geometry.transforms import matrix_from_quaternion

    R_mean = matrix_from_quaternion(np.linalg.eigh(Mq)[1][:, -1])
    res_mm = [float(np.linalg.norm(b[:3, 3] - p_mean) * 1000.0) for b in boards]
    res_deg = [float(np.degrees(np.arccos(np.clip((np.trace(R_mean.T @ b[:3, :3]) - 1) / 2, -1, 1)))) for b in boards]
    return HandEyeResult(
        T_flange_cam=X,
        T_base_board=transform_from(R_mean, p_mean),
        residual_mm=res_mm,
        residual_deg=res_deg,
        n_views=n,
        axis_spread_deg=spread,
    )


def configured_hand_eye(cfg: CellConfig) -> NDArray[np.float64] | None:
    """The configured hand–eye ``T_flange_cam`` (4, 4), or None when ``robot.hand_eye`` is unset.

    Raises:
        ConfigError: the file is missing or invalid (:func:`load_hand_eye`), named as ``robot.hand_eye``.
    """
    if cfg.robot.hand_eye is None:
        return None
    try:
        return load_hand_eye(cfg.path(cfg.robot.hand_eye))
    except ConfigError as err:
        raise ConfigError(f"robot.hand_eye: {err}") from None


def load_hand_eye(path: Path) -> NDArray[np.float64]:
    """``T_flange_cam`` (4, 4) from a file ``cellctl calibrate hand-eye`` wrote.

    Raises:
        ConfigError: the file is missing or not JSON, has no 4×4 ``T_flange_cam_matrix``, its
            rotation is not proper, or the camera is more than :data:`MAX_FLANGE_CAM_M` from the flange.
    """
    if not path.is_file():
        raise ConfigError(f"hand-eye file {str(path)!r} does not exist (write it with `cellctl calibrate hand-eye`)")
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise ConfigError(f"hand-eye file {str(path)!r}: not valid JSON: {err}") from err
    if not isinstance(data, dict) or "T_flange_cam_matrix" not in data:
        raise ConfigError(f"hand-eye file {str(path)!r}: expected an object with key 'T_flange_cam_matrix'")
    try:
        T = check_transform(data["T_flange_cam_matrix"], "T_flange_cam_matrix")
    except (CellError, ValueError, TypeError) as err:
        raise ConfigError(f"hand-eye file {str(path)!r}: {err}") from err
    d = float(np.linalg.norm(T[:3, 3]))
    if d > MAX_FLANGE_CAM_M:
        raise ConfigError(
            f"hand-eye file {str(path)!r}: camera is {d:.3f} m from the flange, expected at most "
            f"{MAX_FLANGE_CAM_M} m (translation in metres)"
        )
    return T
