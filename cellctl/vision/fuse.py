"""Fusion of several views of the same bin into one pose with an uncertainty figure.

Each view gives the board pose in the robot base frame with a covariance from its PnP
Jacobian. A single view is precise across the viewing ray and weak along it (depth), so
views from different observation poses complement each other: positions are fused with
their full 3×3 information matrices, rotations by a weighted quaternion mean (Markley's
eigenvector method). Views inconsistent with the medoid view beyond ``k_sigma`` are
rejected before fusing (a flipped IPPE solution or a motion-blurred frame).

Light module (numpy only).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.transforms import invert, pose_from_transform, transform_from
from cellctl.vision.identify import Identification, not_identified

__all__ = ["FuseSettings", "FusedIdentification", "fuse"]


@dataclass(frozen=True)
class FuseSettings:
    """Parameters of :func:`fuse`.

    Attributes:
        floor_trans_mm: per-view 1-σ error not in the PnP covariance (hand-eye, FK, intrinsics), mm.
        floor_rot_deg: same for rotation, degrees.
        k_sigma: a view farther than this many combined σ from the medoid view is rejected.
    """

    floor_trans_mm: float = 0.5
    floor_rot_deg: float = 0.05
    k_sigma: float = 5.0


@dataclass(frozen=True)
class FusedIdentification:
    """The fused bin pose and how the views agreed.

    Attributes:
        bin_type: the bin type all views agreed on.
        T_base_bin: fused 4×4 bin pose in the base frame.
        T_base_board: fused 4×4 board pose in the base frame.
        views: the input identifications, in order.
        used: indices of the views that entered the fused estimate.
        rejected: indices of views rejected as outliers.
        residual_mm: per view, distance of its board centre to the fused one, mm.
        residual_deg: per view, rotation from its board pose to the fused one, degrees.
        sigma_trans_mm: 1-σ position uncertainty of the fused board centre, mm (the larger of
            the propagated covariance and the scatter of the views).
        sigma_rot_deg: 1-σ rotation uncertainty, degrees (same rule).
        sigma_bin_origin_mm: 1-σ uncertainty of the bin origin (lever arm of the rotation), mm.
    """

    bin_type: str
    T_base_bin: NDArray[np.float64]
    T_base_board: NDArray[np.float64]
    views: list[Identification]
    used: list[int]
    rejected: list[int]
    residual_mm: list[float]
    residual_deg: list[float]
    sigma_trans_mm: float
    sigma_rot_deg: float
    sigma_bin_origin_mm: float

    def to_dict(self) -> dict[str, Any]:
        p, q = pose_from_transform(self.T_base_bin)
        return {
            "bin_type": self.bin_type,
            "T_base_bin": {"position": list(p), "orientation": list(q)},
            "n_views": len(self.views),
            "used": self.used,
            "rejected": self.rejected,
            "residual_mm": [round(x, 4) for x in self.residual_mm],
            "residual_deg": [round(x, 5) for x in self.residual_deg],
            "sigma_trans_mm": round(self.sigma_trans_mm, 4),
            "sigma_rot_deg": round(self.sigma_rot_deg, 5),
            "sigma_bin_origin_mm": round(self.sigma_bin_origin_mm, 4),
            "views": [v.to_dict() for v in self.views],
        }


def _angle_deg(Ra: NDArray[np.float64], Rb: NDArray[np.float64]) -> float:
    c = np.clip((np.trace(Ra.T @ Rb) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(c)))


def _quat(R: NDArray[np.float64]) -> NDArray[np.float64]:
    _, q = pose_from_transform(transform_from(R, np.zeros(3)))
    return np.asarray(q)


def _rot_from_quat(q: NDArray[np.float64]) -> NDArray[np.float64]:
    from cellctl.geometry.transforms import matrix_from_quaternion

    return matrix_from_quaternion(q)


def fuse(identifications: Sequence[Identification], settings: FuseSettings | None = None) -> FusedIdentification:
    """Fuse several identifications of the same bin (different camera poses) into one pose.

    Args:
        identifications: one or more views, each with ``T_base_bin`` in the same base frame.
        settings: fusion parameters.

    Returns:
        The fused estimate with per-view residuals and an uncertainty figure.

    Raises:
        cellctl.errors.IdentificationError: no views, or views that disagree on the bin type.
    """
    st = settings or FuseSettings()
    views = list(identifications)
    if not views:
        raise not_identified("no views", "fuse() got 0 identifications; expected at least one view")
    types = sorted({v.bin_type for v in views})
    if len(types) > 1:
        raise not_identified(
            "two boards", f"views disagree on the bin type: {[v.bin_type for v in views]} (expected one type)"
        )
    T_bin_board = views[0].T_bin_board
    # The board centre is the point a view measures best; fuse there, then map to the bin.
    spec_centre = _centre_from_view(views[0])
    P = []  # board centres in base (3,)
    Rs = []  # board rotations in base
    C = []  # position covariances in base (3, 3), m²
    sr = []  # rotation σ, rad
    ft = st.floor_trans_mm / 1000.0
    fr = np.radians(st.floor_rot_deg)
    for v in views:
        T_base_board = v.T_base_bin @ T_bin_board
        P.append(T_base_board[:3, :3] @ spec_centre + T_base_board[:3, 3])
        Rs.append(T_base_board[:3, :3])
        Rbc = v.T_base_cam[:3, :3]
        C.append(Rbc @ v.cov_board[:3, :3] @ Rbc.T + ft**2 * np.eye(3))
        sr.append(float(np.hypot(np.radians(v.sigma_rot_deg), fr)))
    P_a = np.array(P)
    n = len(views)
    # Medoid view: smallest sum of normalised distances to the others.
    st_i = np.array([np.sqrt(np.trace(c) / 3.0) for c in C])
    D = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            dt = np.linalg.norm(P_a[i] - P_a[j]) / np.hypot(st_i[i], st_i[j])
            dr = np.radians(_angle_deg(Rs[i], Rs[j])) / np.hypot(sr[i], sr[j])
            D[i, j] = max(dt, dr)
    ref = int(np.argmin(D.sum(axis=1)))
    used = [i for i in range(n) if D[i, ref] <= st.k_sigma]
    rejected = [i for i in range(n) if i not in used]
    # Positions: information-weighted mean.
    info = sum(np.linalg.inv(C[i]) for i in used)
    cov_p = np.linalg.inv(info)
    p_f = cov_p @ sum(np.linalg.inv(C[i]) @ P_a[i] for i in used)
    # Rotations: weighted quaternion mean (eigenvector of Σ w q qᵀ).
    M = np.zeros((4, 4))
    w_r = {i: 1.0 / sr[i] ** 2 for i in used}
    for i in used:
        q = _quat(Rs[i])
        M += w_r[i] * np.outer(q, q)
    q_f = np.linalg.eigh(M)[1][:, -1]
    R_f = _rot_from_quat(q_f)
    T_base_board = transform_from(R_f, p_f - R_f @ spec_centre)
    T_base_bin = T_base_board @ invert(T_bin_board)
    res_mm = [float(np.linalg.norm(P_a[i] - p_f) * 1000.0) for i in range(n)]
    res_deg = [_angle_deg(Rs[i], R_f) for i in range(n)]
    # Uncertainty: the larger of the propagated covariance and the scatter of the used views.
    sig_t_int = float(np.sqrt(np.trace(cov_p))) * 1000.0
    sig_r_int = float(np.degrees(1.0 / np.sqrt(sum(w_r.values()))))
    m = len(used)
    if m > 1:
        sig_t_ext = float(np.sqrt(sum(res_mm[i] ** 2 for i in used) / (m * (m - 1))))
        sig_r_ext = float(np.sqrt(sum(res_deg[i] ** 2 for i in used) / (m * (m - 1))))
    else:
        sig_t_ext = sig_r_ext = 0.0
    sig_t = max(sig_t_int, sig_t_ext)
    sig_r = max(sig_r_int, sig_r_ext)
    lever = float(np.linalg.norm(invert(T_bin_board)[:3, 3] - spec_centre))  # board centre ↔ bin origin, m
    sig_bin = float(np.hypot(sig_t, np.radians(sig_r) * lever * 1000.0))
    return FusedIdentification(
        bin_type=types[0],
        T_base_bin=T_base_bin,
        T_base_board=T_base_board,
        views=views,
        used=used,
        rejected=rejected,
        residual_mm=res_mm,
        residual_deg=res_deg,
        sigma_trans_mm=sig_t,
        sigma_rot_deg=sig_r,
        sigma_bin_origin_mm=sig_bin,
    )


def _centre_from_view(v: Identification) -> NDArray[np.float64]:
    """Board centre in the board frame (metres) from the view's board size."""
    w, h = v.board_size_m
    return np.array([w / 2.0, h / 2.0, 0.0])
