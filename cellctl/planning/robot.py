"""The planner's view of the UR10e + camera: the twin's robot model plus planner helpers.

Kinematics, limits, hand-eye and capsules come from :mod:`cellctl.geometry.robot_model`
(one model for sim, planner and supervisor). This module adds what planning needs on top:
all IK solutions of a camera pose without wrapping (wrapping is the caller's choice), the
camera-body capsule for the camera-collision filter, and a model id that changes whenever
anything a plan depends on changes (so a cached plan becomes a cache miss).

Frames: ``base`` = UR DH base, ``flange`` = tool0, ``cam`` = optical frame. Metres, radians.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.geometry import robot_model as rm
from cellctl.geometry.transforms import invert
from cellctl.vision.handeye import configured_hand_eye

if TYPE_CHECKING:
    from cellctl.config import CellConfig

__all__ = ["RobotModel", "default_robot_model"]


@dataclass(frozen=True)
class RobotModel:
    """Kinematic model of the UR10e carrying the eye-in-hand camera.

    Attributes:
        T_flange_cam: (4, 4) camera optical frame in the flange frame.
        q_min, q_max: (6,) joint limits, rad.
        q_home: (6,) configuration tours start from when no current one is given, rad.
    """

    T_flange_cam: NDArray[np.float64] = field(default_factory=lambda: np.array(rm.T_FLANGE_CAM))
    q_min: NDArray[np.float64] = field(default_factory=lambda: np.array(rm.JOINT_LIMITS[:, 0]))
    q_max: NDArray[np.float64] = field(default_factory=lambda: np.array(rm.JOINT_LIMITS[:, 1]))
    q_home: NDArray[np.float64] = field(
        # arm straight up, as cellctl.sim.scene.HOME_JOINTS: clear of any bin around the base
        default_factory=lambda: np.array([np.pi, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0])
    )
    name: str = "ur10e"

    @classmethod
    def from_config(cls, cfg: CellConfig) -> RobotModel:
        """The cell's model with the configured hand–eye (``robot.hand_eye``), else the nominal mount."""
        T = configured_hand_eye(cfg)
        return cls() if T is None else cls(T_flange_cam=T)

    def model_id(self) -> str:
        """Stable id of everything a plan depends on: DH, limits, hand-eye, capsules, platform."""
        blob = json.dumps(
            {
                "name": self.name,
                "dh": [rm.DH_D.tolist(), rm.DH_A.tolist(), rm.DH_ALPHA.tolist()],
                "T_flange_cam": np.round(self.T_flange_cam, 6).tolist(),
                "limits": [np.round(self.q_min, 6).tolist(), np.round(self.q_max, 6).tolist()],
                "capsules": [[c.name, c.link, c.p0, c.p1, c.radius, c.env] for c in rm.CAPSULES],
                "mobile_base": [np.asarray(x).tolist() for x in rm.MOBILE_BASE_BOX],
            },
            sort_keys=True,
        )
        return f"{self.name}-{hashlib.sha256(blob.encode()).hexdigest()[:12]}"

    def fk_frames(self, q: ArrayLike) -> NDArray[np.float64]:
        """(N, 7, 4, 4) DH frames ``T_base_i`` (i = 0 base … 6 flange) of configurations (N, 6)."""
        return rm.link_frames(q)

    def fk_cam(self, q: ArrayLike) -> NDArray[np.float64]:
        """(N, 4, 4) ``T_base_cam`` of configurations (N, 6)."""
        return rm.link_frames(q)[:, 6] @ self.T_flange_cam

    def ik_cam(self, T_base_cam: ArrayLike) -> NDArray[np.float64]:
        """All IK solutions (K ≤ 8, 6) in (−π, π] within the limits placing the camera at ``T_base_cam``."""
        from ur_analytic_ik import ur10e

        T_base_flange = np.asarray(T_base_cam, dtype=np.float64) @ invert(self.T_flange_cam)
        sols = ur10e.inverse_kinematics(np.ascontiguousarray(T_base_flange))
        if not sols:
            return np.zeros((0, 6))
        S = np.asarray(sols, dtype=np.float64).reshape(-1, 6)
        S = S[np.all(np.isfinite(S), axis=1)]
        return S[self.within_limits(S)]

    def ik_cam_many(self, T_base_cam: ArrayLike) -> list[NDArray[np.float64]]:
        """:meth:`ik_cam` for poses (N, 4, 4): one matrix product and one limits test for all
        (the per-pose Python overhead was as large as the analytic IK itself)."""
        from ur_analytic_ik import ur10e

        Ts = np.asarray(T_base_cam, dtype=np.float64).reshape(-1, 4, 4) @ invert(self.T_flange_cam)
        raws = [ur10e.inverse_kinematics(np.ascontiguousarray(T)) for T in Ts]
        n = [len(r) if r is not None else 0 for r in raws]
        if sum(n) == 0:
            return [np.zeros((0, 6)) for _ in raws]
        S = np.concatenate([np.asarray(r, dtype=np.float64).reshape(-1, 6) for r, k in zip(raws, n, strict=True) if k])
        ok = np.all(np.isfinite(S), axis=1) & self.within_limits(S)
        out, at = [], 0
        for k in n:
            out.append(S[at : at + k][ok[at : at + k]] if k else np.zeros((0, 6)))
            at += k
        return out

    def within_limits(self, q: ArrayLike) -> NDArray[np.bool_]:
        """(N,) True where configuration i is within the joint limits."""
        Q = np.atleast_2d(np.asarray(q, dtype=np.float64))
        return np.all((Q >= self.q_min - 1e-9) & (Q <= self.q_max + 1e-9), axis=1)

    def camera_capsule(self, T_x_cam: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        """The camera body's capsule at camera poses ``T_x_cam`` (N, 4, 4), in that frame x.

        Returns:
            ``(p0 (N, 3), p1 (N, 3), radius)`` in metres.
        """
        cap = next(c for c in rm.CAPSULES if c.name == "camera")
        T = np.asarray(T_x_cam, dtype=np.float64).reshape(-1, 4, 4) @ invert(self.T_flange_cam)  # T_x_flange
        p0 = T[:, :3, :3] @ np.array(cap.p0) + T[:, :3, 3]
        p1 = T[:, :3, :3] @ np.array(cap.p1) + T[:, :3, 3]
        return p0, p1, float(cap.radius)


def default_robot_model() -> RobotModel:
    """The cell's UR10e + camera (the twin's robot model)."""
    return RobotModel()
