"""Fast batch collision checks of the UR10e + camera against the bin, the cell and itself.

Why not pybullet queries: ``getClosestPoints`` costs ~360 µs per capsule (notes/planning.md
§6), i.e. ~3 ms per configuration — too slow for planning. Here:

* the robot is its capsules (:data:`cellctl.geometry.robot_model.CAPSULES`), each sampled as
  spheres every :data:`SAMPLE_SPACING_M` along its axis;
* the bin is an **unsigned distance grid** in the bin frame (1 cm, exact point-to-triangle
  distances from Open3D, cached on disk by mesh sha256), looked up by trilinear
  interpolation for all spheres of all configurations at once; spheres the grid finds near
  the surface are re-checked with exact closest-point queries, so the answer is exact up to
  the sphere sampling (≤ 1.7 mm sag between spheres) plus :attr:`CollisionWorld.margin`;
* floor, cabin walls and the mobile base are analytic (planes, box);
* self-collision: exact segment–segment distances of non-adjacent capsule pairs.

Everything is expressed in the robot **base** frame; the bin pose ``T_base_bin`` comes from
the scenario (sim) or from identification (planner). This is the cell's one collision world:
the planner does not model collisions itself, it wraps this class
(:class:`cellctl.planning.collision.PlanningWorld`: bin-frame set-up, camera-only and
batched straight-motion checks for OMPL and the distance matrix). :class:`cellctl.sim.pybullet_world.PyBulletWorld`
cross-checks this model with pybullet.
"""

from __future__ import annotations

import hashlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cellctl.geometry import robot_model as rm
from cellctl.geometry.catalog import BinMesh
from cellctl.geometry.transforms import invert

__all__ = ["CollisionWorld", "DistanceGrid", "SAMPLE_SPACING_M", "segment_distances"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

SAMPLE_SPACING_M = 0.025
GRID_STEP_M = 0.01
GRID_PAD_M = 0.15
_GRIDS: dict[str, DistanceGrid] = {}


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "cellctl"


class DistanceGrid:
    """Unsigned distance to a mesh on a regular grid (bin frame) + exact re-check.

    Args:
        mesh: the bin mesh.
        step: grid step (m).
        pad: margin around the mesh bounding box (m); outside the grid the distance is taken
            as ``pad`` (≥ any capsule radius).
    """

    def __init__(self, mesh: BinMesh, step: float = GRID_STEP_M, pad: float = GRID_PAD_M) -> None:
        import open3d as o3d

        self.step, self.pad = step, pad
        self.lo = mesh.vertices.min(axis=0) - pad
        hi = mesh.vertices.max(axis=0) + pad
        self.shape = tuple(int(np.ceil((hi[i] - self.lo[i]) / step)) + 1 for i in range(3))
        self._scene = o3d.t.geometry.RaycastingScene(nthreads=0)
        self._scene.add_triangles(
            o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.faces.astype(np.uint32))
        )
        key = hashlib.sha256(mesh.vertices.tobytes() + mesh.faces.tobytes()).hexdigest()[:20]
        cache = _cache_dir() / f"udf-{key}-{step:g}-{pad:g}.npy"
        grid = None
        if cache.is_file():
            try:
                grid = np.load(cache)
                if grid.shape != self.shape:
                    grid = None
            except (OSError, ValueError):
                grid = None
        if grid is None:
            axes = [self.lo[i] + step * np.arange(self.shape[i]) for i in range(3)]
            pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3).astype(np.float32)
            grid = self._scene.compute_distance(o3d.core.Tensor(pts)).numpy().reshape(self.shape)
            try:
                cache.parent.mkdir(parents=True, exist_ok=True)
                tmp = cache.with_suffix(f".{os.getpid()}.tmp.npy")
                np.save(tmp, grid.astype(np.float32))
                os.replace(tmp, cache)
            except OSError as err:  # a read-only home only costs a second per start
                log.debug("cannot cache the distance grid: %s", err)
        self.grid = grid.astype(np.float32)

    def interp(self, pts: NDArray[np.float64]) -> NDArray[np.float64]:
        """Interpolated distance (M,) at points (M, 3) in the bin frame (``pad`` outside the grid)."""
        from scipy.ndimage import map_coordinates

        idx = (pts - self.lo) / self.step
        inside = np.all((idx >= 0) & (idx <= np.array(self.shape) - 1), axis=1)
        out = np.full(len(pts), self.pad)
        if inside.any():
            out[inside] = map_coordinates(self.grid, idx[inside].T, order=1, mode="nearest")
        return out

    def exact(self, pts: NDArray[np.float64]) -> NDArray[np.float64]:
        """Exact distance (M,) from points (M, 3) in the bin frame to the mesh."""
        import open3d as o3d

        if len(pts) == 0:
            return np.zeros(0)
        return self._scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy().astype(np.float64)


def distance_grid(mesh: BinMesh) -> DistanceGrid:
    """The (process-wide cached) distance grid of a mesh."""
    key = hashlib.sha256(mesh.vertices.tobytes() + mesh.faces.tobytes()).hexdigest()
    if key not in _GRIDS:
        _GRIDS[key] = DistanceGrid(mesh)
    return _GRIDS[key]


def segment_distances(p0: NDArray, p1: NDArray, q0: NDArray, q1: NDArray) -> NDArray[np.float64]:
    """Shortest distances (N,) between segments p0–p1 and q0–q1 (each (N, 3))."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.einsum("ij,ij->i", d1, d1)
    e = np.einsum("ij,ij->i", d2, d2)
    f = np.einsum("ij,ij->i", d2, r)
    c = np.einsum("ij,ij->i", d1, r)
    b = np.einsum("ij,ij->i", d1, d2)
    denom = a * e - b * b
    s = np.where(denom > 1e-12, np.clip((b * f - c * e) / np.where(denom > 1e-12, denom, 1), 0, 1), 0.0)
    t = (b * s + f) / np.maximum(e, 1e-12)
    t_c = np.clip(t, 0, 1)
    s = np.where(
        t < 0,
        np.clip(-c / np.maximum(a, 1e-12), 0, 1),
        np.where(t > 1, np.clip((b - c) / np.maximum(a, 1e-12), 0, 1), s),
    )
    c1 = p0 + d1 * s[:, None]
    c2 = q0 + d2 * t_c[:, None]
    return np.linalg.norm(c1 - c2, axis=1)


@dataclass
class _Sampled:
    names: list[str]
    link: NDArray[np.int64]  # (S,) link frame of each sphere
    local: NDArray[np.float64]  # (S, 4) homogeneous sphere centre in its link frame
    radius: NDArray[np.float64]  # (S,)
    owner: NDArray[np.int64]  # (S,) capsule index
    env: NDArray[np.bool_]  # (S,) checked against the environment


def _sample_capsules() -> _Sampled:
    link, local, radius, owner, env = [], [], [], [], []
    for ci, c in enumerate(rm.CAPSULES):
        p0, p1 = np.array(c.p0), np.array(c.p1)
        n = max(2, int(np.ceil(np.linalg.norm(p1 - p0) / SAMPLE_SPACING_M)) + 1)
        for f in np.linspace(0, 1, n):
            link.append(c.link)
            local.append([*(p0 + f * (p1 - p0)), 1.0])
            radius.append(c.radius)
            owner.append(ci)
            env.append(c.env)
    return _Sampled(
        [c.name for c in rm.CAPSULES],
        np.array(link),
        np.array(local),
        np.array(radius),
        np.array(owner),
        np.array(env),
    )


_SAMPLES = _sample_capsules()


@dataclass
class _Caps:
    link: NDArray[np.int64]
    p0: NDArray[np.float64]  # (C, 4) homogeneous
    p1: NDArray[np.float64]
    radius: NDArray[np.float64]


_CAPS = _Caps(
    np.array([c.link for c in rm.CAPSULES]),
    np.array([[*c.p0, 1.0] for c in rm.CAPSULES]),
    np.array([[*c.p1, 1.0] for c in rm.CAPSULES]),
    np.array([c.radius for c in rm.CAPSULES]),
)


class CollisionWorld:
    """The robot's surroundings in its base frame, with batch collision queries.

    Args:
        bin_mesh: the bin mesh (bin frame), or None for an empty cell.
        T_base_bin: bin pose in the robot base frame (4, 4).
        T_base_world: world (floor) frame in the robot base frame; default: base level at
            :data:`~cellctl.geometry.robot_model.BASE_HEIGHT_M` above the floor.
        walls: cabin half-extents (x, y) in the world frame, or None for no walls.
        margin: extra clearance (m) required around every capsule.
    """

    def __init__(
        self,
        bin_mesh: BinMesh | None,
        T_base_bin: ArrayLike | None = None,
        T_base_world: ArrayLike | None = None,
        walls: tuple[float, float] | None = (2.5, 2.5),
        margin: float = 0.005,
    ) -> None:
        self.mesh = bin_mesh
        self.grid = distance_grid(bin_mesh) if bin_mesh is not None else None
        self.T_base_bin = np.eye(4) if T_base_bin is None else np.asarray(T_base_bin, dtype=np.float64)
        if T_base_world is None:
            T_base_world = np.eye(4)
            T_base_world[2, 3] = -rm.BASE_HEIGHT_M
        self.T_base_world = np.asarray(T_base_world, dtype=np.float64)
        self.walls = walls
        self.margin = margin
        self.n_checked = 0
        self._T_bin_base = invert(self.T_base_bin)
        self._T_world_base = invert(self.T_base_world)
        c, s = rm.MOBILE_BASE_BOX
        self._box_lo, self._box_hi = c - s / 2, c + s / 2
        names = [cap.name for cap in rm.CAPSULES]
        self._pairs = np.array([(names.index(a), names.index(b)) for a, b in rm.SELF_PAIRS])

    def set_bin_pose(self, T_base_bin: ArrayLike) -> None:
        self.T_base_bin = np.asarray(T_base_bin, dtype=np.float64)
        self._T_bin_base = invert(self.T_base_bin)

    def _spheres(self, Q: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        frames = rm.link_frames(Q)  # (N, 7, 4, 4)
        S = _SAMPLES
        pts = np.einsum("nsij,sj->nsi", frames[:, S.link], S.local)[..., :3]  # (N, S, 3)
        return pts, frames

    def check(self, q: ArrayLike) -> NDArray[np.bool_]:
        """Collision flags (N,) for configurations (N, 6) or (6,) (True = in collision)."""
        Q = np.atleast_2d(np.asarray(q, dtype=np.float64))
        return self._check(Q, explain=False)[0]

    def in_collision(self, q: ArrayLike) -> bool:
        """True if one configuration (6,) collides."""
        return bool(self.check(q)[0])

    def explain(self, q: ArrayLike) -> list[str]:
        """What one configuration (6,) collides with, e.g. ``['camera vs bin', 'wrist_3 vs upper_arm']``."""
        Q = np.atleast_2d(np.asarray(q, dtype=np.float64))
        return self._check(Q, explain=True)[1]

    def _check(self, Q: NDArray[np.float64], explain: bool) -> tuple[NDArray[np.bool_], list[str]]:
        N = len(Q)
        self.n_checked += N
        pts, frames = self._spheres(Q)
        S = _SAMPLES
        r = S.radius + self.margin
        hit = np.zeros((N, len(S.radius)), dtype=bool)
        what: list[str] = []
        env = S.env
        # floor and walls (world frame)
        pw = pts @ self._T_world_base[:3, :3].T + self._T_world_base[:3, 3]
        floor = (pw[..., 2] < r) & env
        hit |= floor
        if self.walls is not None:
            wx, wy = self.walls
            wall = ((np.abs(pw[..., 0]) > wx - r) | (np.abs(pw[..., 1]) > wy - r)) & env
            hit |= wall
        # mobile base box (base frame), not for capsules mounted on it
        d_box = np.linalg.norm(np.maximum(np.maximum(self._box_lo - pts, pts - self._box_hi), 0.0), axis=-1)
        box = (d_box < r) & env & (S.link[None, :] >= 2)
        hit |= box
        # bin: grid first, exact distances for the spheres near the surface
        binhit = np.zeros_like(hit)
        if self.grid is not None:
            pb = pts @ self._T_bin_base[:3, :3].T + self._T_bin_base[:3, 3]
            flat = pb.reshape(-1, 3)
            rr = np.broadcast_to(r, hit.shape).reshape(-1)
            d = self.grid.interp(flat)
            near = d < rr + self.grid.step
            if near.any():
                idx = np.flatnonzero(near)
                binhit.reshape(-1)[idx] = self.grid.exact(flat[idx]) < rr[idx]
            binhit &= env
            hit |= binhit
        coll = hit.any(axis=1)
        # self-collision of non-adjacent capsule pairs (all pairs of all configurations at once)
        selfhit = np.zeros((N, len(self._pairs)), dtype=bool)
        if len(self._pairs):
            C = _CAPS
            e0 = np.einsum("ncij,cj->nci", frames[:, C.link], C.p0)[..., :3]
            e1 = np.einsum("ncij,cj->nci", frames[:, C.link], C.p1)[..., :3]
            a, b = self._pairs[:, 0], self._pairs[:, 1]
            d = segment_distances(
                e0[:, a].reshape(-1, 3),
                e1[:, a].reshape(-1, 3),
                e0[:, b].reshape(-1, 3),
                e1[:, b].reshape(-1, 3),
            ).reshape(N, -1)
            selfhit = d < (C.radius[a] + C.radius[b])
            coll |= selfhit.any(axis=1)
        if explain:
            names = S.names
            for label, m in (
                ("floor", floor),
                ("cell wall", wall if self.walls is not None else None),
                ("mobile base", box),
                ("bin", binhit),
            ):
                if m is None:
                    continue
                for ci in sorted(set(S.owner[m[0]].tolist())):
                    what.append(f"{names[ci]} vs {label}")
            if len(self._pairs):
                for k in np.flatnonzero(selfhit[0]):
                    a, b = self._pairs[k]
                    what.append(f"{names[a]} vs {names[b]}")
        return coll, what

    def path_free(self, path: ArrayLike, step: float = 0.01) -> bool:
        """True if the piecewise-linear joint path (K, 6) is collision-free at ``step`` rad resolution."""
        return bool(not self.check(densify(path, step)).any())


def densify(path: ArrayLike, step: float = 0.01) -> NDArray[np.float64]:
    """Joint path (K, 6) resampled so no joint moves more than ``step`` rad between samples."""
    P = np.atleast_2d(np.asarray(path, dtype=np.float64))
    out = [P[:1]]
    for a, b in zip(P[:-1], P[1:], strict=True):
        n = max(1, int(np.ceil(np.abs(b - a).max() / step)))
        f = np.linspace(0, 1, n + 1)[1:, None]
        out.append(a + f * (b - a))
    return np.vstack(out)
