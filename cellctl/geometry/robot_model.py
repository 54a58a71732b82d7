"""UR10e on a mobile base with an eye-in-hand camera: kinematics and collision geometry.

One model for the sim, the planner and the supervisor. Light: numpy only at import; the
analytic IK (``ur-analytic-ik``) is imported on first use. No pybullet.

Frames (``T_a_b`` maps points in b into a):

* ``base``: the UR controller/DH base frame (= ROS ``base_link`` rotated 180° about z), the
  frame of ``ur_analytic_ik``; +Z up, origin on the mounting plate. All robot-level poses on
  the wire (``MoveRequest.camera_pose``, ``RobotState``) are in this frame.
* ``flange``: UR ``tool0``; +Z out of the tool plate.
* ``cam``: the camera optical frame (+Z forward, +X right, +Y down). ``T_flange_cam`` is the
  paper's Table 1 ``opt_H_cam`` read as the pose of the optical frame in the camera-mesh
  frame, the camera mesh being modelled at the flange: a pure offset (0.118, 0.058, -0.035) m,
  optical axis parallel to the flange's +Z.
* ``world``: the cabin floor (z = 0); the robot base stands on the mobile base at
  :data:`BASE_HEIGHT_M`.

Collision model: every link is a set of capsules (segment + radius) in a DH link frame,
radii from MuJoCo Menagerie's ``ur10e.xml`` (notes/planning.md §5); the camera body is a
box :data:`CAMERA_BOX_SIZE` approximated by a capsule; the mobile base is a box in the base frame.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.errors import RobotError
from cellctl.geometry.transforms import invert, transform_from

__all__ = [
    "BASE_HEIGHT_M",
    "CAMERA_BOX_SIZE",
    "CAPSULES",
    "Capsule",
    "DH_A",
    "DH_ALPHA",
    "DH_D",
    "JOINT_LIMITS",
    "JOINT_NAMES",
    "MAX_JOINT_SPEED",
    "MOBILE_BASE_BOX",
    "REACH_M",
    "T_FLANGE_CAM",
    "camera_pose",
    "check_joints",
    "fk",
    "fk_batch",
    "ik",
    "ik_camera",
    "ik_many",
    "link_frames",
    "unreachable_reason",
    "view_blocked",
    "wrap_near",
]

JOINT_NAMES = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")

DH_D = np.array([0.1807, 0.0, 0.0, 0.17415, 0.11985, 0.11655])
DH_A = np.array([0.0, -0.6127, -0.57155, 0.0, 0.0, 0.0])
DH_ALPHA = np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])
"""UR10e DH parameters (m, rad), as in ur-analytic-ik ``dh_parameters.hh``."""

JOINT_LIMITS = np.array([[-2 * np.pi, 2 * np.pi]] * 6)
JOINT_LIMITS[2] = (-np.pi, np.pi)  # the elbow cannot turn past about ±pi (cable/self-collision)
"""(6, 2) joint position limits (rad)."""

MAX_JOINT_SPEED = np.radians([120.0, 120.0, 180.0, 180.0, 180.0, 180.0])
"""Joint speed limits (rad/s), UR10e manual."""

REACH_M = 1.3
"""Nominal reach of the UR10e (paper Table 1 r̄)."""

T_FLANGE_CAM = transform_from(np.eye(3), [0.118, 0.058, -0.035])
"""Camera optical frame in the flange frame (paper Table 1 ``opt_H_cam``)."""

CAMERA_BOX_SIZE = (0.10, 0.07, 0.06)
"""Camera body (x, y, z) in metres; front face 5 mm behind the optical origin (centre z_cam -0.035 m)."""

BASE_HEIGHT_M = 0.70
"""Height of the robot base (mounting plate) above the floor, on top of the mobile base."""

MOBILE_BASE_BOX = (np.array([-0.25, 0.0, -0.35]), np.array([0.85, 0.62, 0.70]))
"""Mobile base as (centre, size) in the robot base frame; the arm is mounted near its +x edge."""


@dataclass(frozen=True)
class Capsule:
    """A capsule: segment ``p0``–``p1`` (m) in link frame ``link`` (0 = base … 6 = flange), radius (m)."""

    name: str
    link: int
    p0: tuple[float, float, float]
    p1: tuple[float, float, float]
    radius: float
    env: bool = True  # checked against the environment (the base column never moves)


CAPSULES: tuple[Capsule, ...] = (
    Capsule("base", 0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.17), 0.078, env=False),
    Capsule("shoulder", 1, (0.0, 0.0, -0.02), (0.0, 0.0, 0.21), 0.078),
    Capsule("upper_arm", 2, (0.6127, 0.0, 0.176), (0.0, 0.0, 0.176), 0.065),
    Capsule("elbow", 2, (0.0, 0.0, 0.2), (0.0, 0.0, 0.02), 0.065),
    Capsule("forearm", 3, (0.57155, 0.0, 0.04), (0.0, 0.0, 0.04), 0.05),
    Capsule("wrist_1", 3, (0.0, 0.0, 0.02), (0.0, 0.0, 0.22), 0.05),
    Capsule("wrist_2", 4, (0.0, 0.0, -0.05), (0.0, 0.0, 0.12), 0.046),
    Capsule("wrist_3", 5, (0.0, 0.0, -0.04), (0.0, 0.0, 0.12), 0.046),
    # camera body: box CAMERA_BOX_SIZE behind the optical origin, as a capsule along flange x
    Capsule("camera", 6, (0.118 - 0.035, 0.058, -0.075), (0.118 + 0.035, 0.058, -0.075), 0.035),
)
"""Collision capsules of the arm and the camera."""

SELF_PAIRS: tuple[tuple[str, str], ...] = (
    ("camera", "upper_arm"),
    ("camera", "forearm"),
    ("camera", "shoulder"),
    ("camera", "base"),
    ("wrist_2", "upper_arm"),
    ("wrist_3", "upper_arm"),
    ("wrist_2", "shoulder"),
    ("wrist_3", "shoulder"),
    ("wrist_3", "base"),
    ("forearm", "base"),
)
"""Non-adjacent capsule pairs checked for self-collision."""


def check_joints(q: ArrayLike, name: str = "joints") -> NDArray[np.float64]:
    """``q`` as a (6,) float array within :data:`JOINT_LIMITS`; else RobotError naming the joint."""
    a = np.asarray(q, dtype=np.float64)
    if a.shape != (6,) or not np.all(np.isfinite(a)):
        raise RobotError(f"{name} must be 6 finite joint angles (rad), got {np.asarray(q).tolist()}")
    for i, (lo, hi) in enumerate(JOINT_LIMITS):
        if not lo - 1e-9 <= a[i] <= hi + 1e-9:
            raise RobotError(
                f"{name}: joint {JOINT_NAMES[i]} = {a[i]:.4f} rad is outside its limits [{lo:.4f}, {hi:.4f}] rad"
            )
    return a


def _dh(theta: NDArray[np.float64], i: int) -> NDArray[np.float64]:
    """Batch DH transforms (N, 4, 4) of joint ``i`` at angles ``theta`` (N,)."""
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(DH_ALPHA[i]), np.sin(DH_ALPHA[i])
    T = np.zeros((len(theta), 4, 4))
    T[:, 0, 0], T[:, 0, 1], T[:, 0, 2], T[:, 0, 3] = ct, -st * ca, st * sa, DH_A[i] * ct
    T[:, 1, 0], T[:, 1, 1], T[:, 1, 2], T[:, 1, 3] = st, ct * ca, -ct * sa, DH_A[i] * st
    T[:, 2, 1], T[:, 2, 2], T[:, 2, 3] = sa, ca, DH_D[i]
    T[:, 3, 3] = 1.0
    return T


def link_frames(q: ArrayLike) -> NDArray[np.float64]:
    """DH link frames in the base frame for a batch of configurations.

    Args:
        q: (N, 6) or (6,) joint angles (rad).

    Returns:
        (N, 7, 4, 4): ``T_base_link_k`` for k = 0 (base) … 6 (flange).
    """
    Q = np.atleast_2d(np.asarray(q, dtype=np.float64))
    N = Q.shape[0]
    out = np.empty((N, 7, 4, 4))
    out[:, 0] = np.eye(4)
    for i in range(6):
        out[:, i + 1] = out[:, i] @ _dh(Q[:, i], i)
    return out


def fk_batch(q: ArrayLike) -> NDArray[np.float64]:
    """``T_base_flange`` (N, 4, 4) of a batch of configurations (N, 6)."""
    return link_frames(q)[:, 6]


def fk(q: ArrayLike) -> NDArray[np.float64]:
    """``T_base_flange`` (4, 4) of one configuration (6,) rad."""
    return link_frames(q)[0, 6]


def camera_pose(q: ArrayLike, T_flange_cam: ArrayLike | None = None) -> NDArray[np.float64]:
    """``T_base_cam`` (4, 4) of one configuration; ``T_flange_cam`` None: the mount :data:`T_FLANGE_CAM`."""
    return fk(q) @ _flange_cam(T_flange_cam)


def _flange_cam(T_flange_cam: ArrayLike | None) -> NDArray[np.float64]:
    return T_FLANGE_CAM if T_flange_cam is None else np.asarray(T_flange_cam, dtype=np.float64)


def wrap_near(q: NDArray[np.float64], q_ref: NDArray[np.float64]) -> NDArray[np.float64]:
    """Shift each joint by multiples of 2π to be nearest ``q_ref`` while staying within limits."""
    out = np.array(q, dtype=np.float64)
    for i in range(6):
        lo, hi = JOINT_LIMITS[i]
        cands = out[i] + 2 * np.pi * np.array([-2, -1, 0, 1, 2])
        cands = cands[(cands >= lo - 1e-12) & (cands <= hi + 1e-12)]
        if len(cands):
            out[i] = cands[np.argmin(np.abs(cands - q_ref[i]))]
    return out


_STDOUT_LOCK = threading.RLock()  # re-entrant: a caller may silence a whole run that calls ik()


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Silence fd 1 while ur-analytic-ik runs: its C++ code prints warnings about filtered
    near-singular solutions on stdout, which would corrupt JSON output of benches."""
    with _STDOUT_LOCK:
        try:
            sys.stdout.flush()
            saved = os.dup(1)
        except (OSError, ValueError):  # no real fd 1 (embedded interpreters): just run
            yield
            return
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, 1)
            yield
        finally:
            os.dup2(saved, 1)
            os.close(saved)
            os.close(devnull)


def ik(T_base_flange: ArrayLike, q_near: ArrayLike | None = None) -> NDArray[np.float64]:
    """All analytic IK solutions (≤ 8) for a flange pose, within joint limits.

    Each solution is shifted by 2π per joint toward ``q_near`` (default: zeros) and the
    solutions are sorted by joint-space distance to it.

    Returns:
        (k, 6) array, k = 0 when the pose is out of reach.
    """
    from ur_analytic_ik import ur10e

    T = np.asarray(T_base_flange, dtype=np.float64)
    ref = np.zeros(6) if q_near is None else np.asarray(q_near, dtype=np.float64)
    with _quiet_stdout():
        raw = ur10e.inverse_kinematics(T)
    return _select(raw, ref)


def ik_many(T_base_flange: ArrayLike, q_near: ArrayLike | None = None) -> list[NDArray[np.float64]]:
    """:func:`ik` for a batch of flange poses (N, 4, 4), with one stdout guard for all (faster)."""
    from ur_analytic_ik import ur10e

    Ts = np.asarray(T_base_flange, dtype=np.float64).reshape(-1, 4, 4)
    ref = np.zeros(6) if q_near is None else np.asarray(q_near, dtype=np.float64)
    with _quiet_stdout():
        raws = [ur10e.inverse_kinematics(T) for T in Ts]
    return [_select(r, ref) for r in raws]


def _select(raw: object, ref: NDArray[np.float64]) -> NDArray[np.float64]:
    """Wrap toward ``ref``, drop out-of-limit solutions, sort by distance to ``ref``."""
    if len(raw) == 0:  # type: ignore[arg-type]
        return np.zeros((0, 6))
    S = np.asarray(raw, dtype=np.float64).reshape(-1, 6)
    S = S[np.all(np.isfinite(S), axis=1)]
    # shift every joint by the multiple of 2π nearest q_near, then keep what is within limits
    S = S + 2 * np.pi * np.round((ref - S) / (2 * np.pi))
    lo, hi = JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1]
    S = np.where(S > hi + 1e-9, S - 2 * np.pi, np.where(S < lo - 1e-9, S + 2 * np.pi, S))
    S = S[np.all((S >= lo - 1e-9) & (S <= hi + 1e-9), axis=1)]
    if len(S) == 0:
        return np.zeros((0, 6))
    return S[np.argsort(np.linalg.norm(S - ref, axis=1), kind="stable")]


def ik_camera(
    T_base_cam: ArrayLike, q_near: ArrayLike | None = None, T_flange_cam: ArrayLike | None = None
) -> NDArray[np.float64]:
    """All IK solutions (k, 6) that put the camera optical frame at ``T_base_cam``."""
    return ik(np.asarray(T_base_cam, dtype=np.float64) @ invert(_flange_cam(T_flange_cam)), q_near)


def unreachable_reason(T_base_cam: ArrayLike, T_flange_cam: ArrayLike | None = None) -> str:
    """Why a camera pose has no IK solution, in words with the numbers."""
    T = np.asarray(T_base_cam, dtype=np.float64) @ invert(_flange_cam(T_flange_cam))
    wrist = T[:3, 3] - DH_D[5] * T[:3, 2]
    d = float(np.linalg.norm(wrist - np.array([0.0, 0.0, DH_D[0]])))
    max_d = abs(DH_A[1]) + abs(DH_A[2]) + 0.05
    if d > max_d:
        return f"wrist centre is {d:.3f} m from the shoulder, beyond the arm's {max_d:.3f} m"
    return f"no analytic IK solution within the joint limits (wrist centre {d:.3f} m from the shoulder)"


def view_blocked(q: ArrayLike, distance: float = 0.4, T_flange_cam: ArrayLike | None = None) -> bool:
    """True if the arm itself blocks the camera's optical axis within ``distance`` (m)."""
    frames = link_frames(q)[0]
    T_cam = frames[6] @ _flange_cam(T_flange_cam)
    s = np.linspace(0.02, distance, 24)
    pts = T_cam[:3, 3] + s[:, None] * T_cam[:3, 2]
    for cap in CAPSULES:
        if cap.name == "camera":
            continue
        T = frames[cap.link]
        a = T[:3, :3] @ np.array(cap.p0) + T[:3, 3]
        b = T[:3, :3] @ np.array(cap.p1) + T[:3, 3]
        ab = b - a
        t = np.clip((pts - a) @ ab / max(ab @ ab, 1e-12), 0, 1)
        d = np.linalg.norm(pts - (a + t[:, None] * ab), axis=1)
        if np.any(d < cap.radius + 0.01):
            return True
    return False
