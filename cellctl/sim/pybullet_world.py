"""The same cell in pybullet (DIRECT): floor, cabin walls, mobile base, the bin as a concave
triangle mesh, and the arm's capsules — an independent cross-check of
:class:`cellctl.sim.collision.CollisionWorld` (tests) and a world for pybullet-based tools.

Queries use ``getClosestPoints`` per capsule pair: static bodies give no contacts in
``performCollisionDetection`` (bullet3#3811), and ~0.4 ms per pair is too slow for
planning, which is why the planner and the sim robot use the distance-grid checker.
All bodies live in the robot **base** frame.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.geometry import robot_model as rm
from cellctl.geometry.catalog import BinMesh
from cellctl.geometry.transforms import quaternion_from_matrix, rotation_about
from cellctl.sim.scene import CABIN_HALF, CABIN_HEIGHT

__all__ = ["PyBulletWorld"]


def _pose(T: NDArray[np.float64]) -> tuple[list[float], list[float]]:
    return T[:3, 3].tolist(), quaternion_from_matrix(T[:3, :3]).tolist()


class PyBulletWorld:
    """A private pybullet DIRECT client holding the cell around one robot base.

    Args:
        mesh: the bin mesh (bin frame).
        T_base_bin: bin pose in the robot base frame.
        T_base_world: world (floor) frame in the robot base frame.
        margin: clearance (m) below which a pair counts as colliding.
    """

    def __init__(self, mesh: BinMesh, T_base_bin: ArrayLike, T_base_world: ArrayLike, margin: float = 0.005) -> None:
        import pybullet as p

        self.p = p
        self.cid = p.connect(p.DIRECT)
        self.margin = margin
        Tbb = np.asarray(T_base_bin, dtype=np.float64)
        Tbw = np.asarray(T_base_world, dtype=np.float64)
        kw = {"physicsClientId": self.cid}
        shape = p.createCollisionShape(
            p.GEOM_MESH,
            vertices=mesh.vertices.tolist(),
            indices=mesh.faces.ravel().tolist(),
            flags=p.GEOM_FORCE_CONCAVE_TRIMESH,
            **kw,
        )
        pos, orn = _pose(Tbb)
        self.env: dict[str, int] = {"bin": p.createMultiBody(0, shape, basePosition=pos, baseOrientation=orn, **kw)}
        floor = p.createCollisionShape(p.GEOM_BOX, halfExtents=[CABIN_HALF[0], CABIN_HALF[1], 0.05], **kw)
        T = Tbw.copy()
        T[:3, 3] = Tbw[:3, :3] @ [0, 0, -0.05] + Tbw[:3, 3]
        pos, orn = _pose(T)
        self.env["floor"] = p.createMultiBody(0, floor, basePosition=pos, baseOrientation=orn, **kw)
        for i, (cx, cy, hx, hy) in enumerate(
            (
                (CABIN_HALF[0] + 0.05, 0, 0.05, CABIN_HALF[1]),
                (-CABIN_HALF[0] - 0.05, 0, 0.05, CABIN_HALF[1]),
                (0, CABIN_HALF[1] + 0.05, CABIN_HALF[0], 0.05),
                (0, -CABIN_HALF[1] - 0.05, CABIN_HALF[0], 0.05),
            )
        ):
            wall = p.createCollisionShape(p.GEOM_BOX, halfExtents=[hx, hy, CABIN_HEIGHT / 2], **kw)
            T = Tbw.copy()
            T[:3, 3] = Tbw[:3, :3] @ [cx, cy, CABIN_HEIGHT / 2] + Tbw[:3, 3]
            pos, orn = _pose(T)
            self.env[f"wall{i}"] = p.createMultiBody(0, wall, basePosition=pos, baseOrientation=orn, **kw)
        c, s = rm.MOBILE_BASE_BOX
        box = p.createCollisionShape(p.GEOM_BOX, halfExtents=(np.asarray(s) / 2).tolist(), **kw)
        self.env["mobile base"] = p.createMultiBody(0, box, basePosition=np.asarray(c).tolist(), **kw)
        self.caps: list[int] = []
        for cap in rm.CAPSULES:
            L = float(np.linalg.norm(np.subtract(cap.p1, cap.p0)))
            sh = p.createCollisionShape(p.GEOM_CAPSULE, radius=cap.radius, height=L, **kw)
            self.caps.append(p.createMultiBody(0, sh, **kw))
        names = [c.name for c in rm.CAPSULES]
        self._pairs = [(names.index(a), names.index(b)) for a, b in rm.SELF_PAIRS]

    def _place(self, q: ArrayLike) -> None:
        frames = rm.link_frames(q)[0]
        z = np.array([0.0, 0.0, 1.0])
        for body, cap in zip(self.caps, rm.CAPSULES, strict=True):
            p0, p1 = np.array(cap.p0), np.array(cap.p1)
            ax = (p1 - p0) / np.linalg.norm(p1 - p0)
            v = np.cross(z, ax)
            R = (
                rotation_about(v, float(np.arccos(np.clip(ax @ z, -1, 1))))
                if np.linalg.norm(v) > 1e-9
                else (np.eye(3) if ax[2] > 0 else np.diag([1.0, -1.0, -1.0]))
            )
            T = np.eye(4)
            T[:3, :3] = frames[cap.link][:3, :3] @ R
            T[:3, 3] = frames[cap.link][:3, :3] @ ((p0 + p1) / 2) + frames[cap.link][:3, 3]
            pos, orn = _pose(T)
            self.p.resetBasePositionAndOrientation(body, pos, orn, physicsClientId=self.cid)

    def collisions(self, q: ArrayLike) -> list[str]:
        """What configuration ``q`` collides with (same labels as CollisionWorld.explain)."""
        self._place(q)
        out = []
        gcp = self.p.getClosestPoints
        for body, cap in zip(self.caps, rm.CAPSULES, strict=True):
            if not cap.env:
                continue
            for label, env in self.env.items():
                if label == "mobile base" and cap.link < 2:
                    continue
                if gcp(body, env, distance=self.margin, physicsClientId=self.cid):
                    out.append(f"{cap.name} vs {'cell wall' if label.startswith('wall') else label}")
        for a, b in self._pairs:
            if gcp(self.caps[a], self.caps[b], distance=0.0, physicsClientId=self.cid):
                out.append(f"{rm.CAPSULES[a].name} vs {rm.CAPSULES[b].name}")
        return out

    def in_collision(self, q: ArrayLike) -> bool:
        return bool(self.collisions(q))

    def close(self) -> None:
        if self.cid is not None:
            self.p.disconnect(physicsClientId=self.cid)
            self.cid = None
