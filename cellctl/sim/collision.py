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
* broad phase: a sphere is looked up in the grid only where the grid's minimum over its 4 cm
  block (:func:`_block_min`, a lower bound of every trilinear value there) is below its
  threshold — the flags are those of looking every sphere up (case-study plan: collision CPU
  ~2.5× lower, the plan unchanged);
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
COARSE_BLOCK = 4
"""Grid cells per axis of one block of :meth:`DistanceGrid.near_index`'s lower bound (4 cm at 1 cm)."""


def _block_min(grid: NDArray[np.float32], block: int) -> NDArray[np.float32]:
    """Per block of ``block``³ cells, the minimum of the grid over its corners (block + 1 points a side).

    Entry ``[I, J, K]`` bounds from below the trilinear value at any point whose cell's lower
    corner lies in ``[block·I, block·I + block)`` (each axis): its 8 corners are in that range + 1.
    """
    g = grid
    for ax in range(3):
        n = g.shape[ax]
        nb = (n - 1) // block + 1  # blocks covering lower corners 0 … n-1
        want = nb * block + 1
        if want > n:  # pad with the last value repeated: never lowers a minimum below a real one
            pad = [(0, 0)] * 3
            pad[ax] = (0, want - n)
            g = np.pad(g, pad, mode="edge")
        g = np.moveaxis(g, ax, 0)
        body = g[: nb * block].reshape(nb, block, *g.shape[1:]).min(axis=1)
        g = np.moveaxis(np.minimum(body, g[block::block][:nb]), 0, ax)
    return np.ascontiguousarray(g)


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
        self._block_min = _block_min(self.grid, COARSE_BLOCK)

    def interp(self, pts: NDArray[np.float64]) -> NDArray[np.float64]:
        """Interpolated distance (M,) at points (M, 3) in the bin frame (``pad`` outside the grid)."""
        from scipy.ndimage import map_coordinates

        idx = (pts - self.lo) / self.step
        inside = np.all((idx >= 0) & (idx <= np.array(self.shape) - 1), axis=1)
        out = np.full(len(pts), self.pad)
        if inside.any():
            out[inside] = map_coordinates(self.grid, idx[inside].T, order=1, mode="nearest")
        return out

    def near_index(self, G: NDArray[np.float64], thr: NDArray[np.float64]) -> NDArray[np.bool_]:
        """``interp(p) < thr`` for points given in grid-index units, ``G`` (N, 3, E), ``thr`` (E,) → (N, E).

        The same flags as :meth:`interp` (``pad`` outside the grid), but most points never reach
        the trilinear lookup: a trilinear value is a convex combination of its cell's 8 corners,
        so it is ≥ the minimum of the grid over the :data:`COARSE_BLOCK`³ block around the cell
        (:func:`_block_min`, a few kB, one gather). Only points whose block minimum is below
        ``thr`` are interpolated — the spheres within a few cm of the bin.
        """
        from scipy.ndimage import map_coordinates

        top = np.array(self.shape, dtype=np.float64)[None, :, None] - 1
        inside = ((G >= 0) & (G <= top)).all(axis=1)
        bm = self._block_min
        blk = np.clip(G, 0.0, top).astype(np.intp) // COARSE_BLOCK  # (N, 3, E), floor of a value ≥ 0
        lower = bm[blk[:, 0], blk[:, 1], blk[:, 2]]  # (N, E) lower bound of the trilinear value
        cand = np.where(inside, lower < thr, self.pad < thr)
        out = np.zeros(cand.shape, dtype=bool)
        n_i, e_i = np.nonzero(cand & inside)
        if len(n_i):
            d = map_coordinates(self.grid, G[n_i, :, e_i].T, order=1, mode="nearest")
            out[n_i, e_i] = d < thr[e_i]
        out |= cand & ~inside  # outside the grid the distance is ``pad`` (< thr here)
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
class _EnvSpheres:
    """The spheres checked against the environment, grouped by link (one small matmul per link).

    Why grouped: gathering a 4×4 frame per sphere (``frames[:, link]``, N × S × 16 doubles) made
    the sphere centres the largest memory stream of a check; per link it is N × 3 × 4 · 4 × S_l.
    """

    links: tuple[int, ...]
    local: tuple[NDArray[np.float64], ...]  # per link (4, S_l): homogeneous centres, columns
    radius: NDArray[np.float64]  # (E,) in the grouped order
    owner: NDArray[np.int64]  # (E,) capsule index
    on_arm: NDArray[np.bool_]  # (E,) link ≥ 2: checked against the mobile base box


def _group_env(S: _Sampled) -> _EnvSpheres:
    links, local, order = [], [], []
    for link in sorted(set(S.link[S.env].tolist())):
        idx = np.flatnonzero(S.env & (S.link == link))
        links.append(int(link))
        local.append(np.ascontiguousarray(S.local[idx].T))
        order.append(idx)
    o = np.concatenate(order)
    return _EnvSpheres(tuple(links), tuple(local), S.radius[o], S.owner[o], S.link[o] >= 2)


_ENV = _group_env(_SAMPLES)


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
        # The planner's hot loop (~60 % of a whole-bin plan's CPU): every array here is (N, E) per
        # coordinate (no (N, S, 3) strided views, no per-sphere 4×4 gathers), squared distances
        # where a root is not needed, one grid lookup over all spheres without boolean scatter.
        # The flags are those of the plain formulation (tests/sim/test_collision.py checks it).
        N = len(Q)
        self.n_checked += N
        frames = rm.link_frames(Q)  # (N, 7, 4, 4)
        E = _ENV
        # sphere centres in the base frame, (N, 3, E): one (N, 3, 4) @ (4, S_l) per link
        P = np.concatenate([frames[:, link, :3, :] @ loc for link, loc in zip(E.links, E.local, strict=True)], axis=2)
        x, y, z = P[:, 0], P[:, 1], P[:, 2]
        r = E.radius + self.margin  # (E,)
        # floor and walls (world frame)
        Rw, tw = self._T_world_base[:3, :3], self._T_world_base[:3, 3]
        zw = Rw[2, 0] * x + Rw[2, 1] * y + Rw[2, 2] * z + tw[2]
        floor = zw < r
        hit = floor.copy()
        wall = None
        if self.walls is not None:
            wx, wy = self.walls
            xw = Rw[0, 0] * x + Rw[0, 1] * y + Rw[0, 2] * z + tw[0]
            yw = Rw[1, 0] * x + Rw[1, 1] * y + Rw[1, 2] * z + tw[1]
            wall = (np.abs(xw) > wx - r) | (np.abs(yw) > wy - r)
            hit |= wall
        # mobile base box (base frame), not for capsules mounted on it
        lo, hi = self._box_lo, self._box_hi
        dx = np.maximum(np.maximum(lo[0] - x, x - hi[0]), 0.0)
        dy = np.maximum(np.maximum(lo[1] - y, y - hi[1]), 0.0)
        dz = np.maximum(np.maximum(lo[2] - z, z - hi[2]), 0.0)
        box = (dx * dx + dy * dy + dz * dz < r * r) & E.on_arm
        hit |= box
        # bin: grid first, exact distances for the spheres near the surface
        binhit = None
        if self.grid is not None:
            g = self.grid
            # grid coordinates straight from the base frame: (R p + t - lo) / step
            Rb, tb = self._T_bin_base[:3, :3], self._T_bin_base[:3, 3]
            G = np.einsum("ij,njk->nik", Rb / g.step, P)
            G += ((tb - g.lo) / g.step)[None, :, None]
            near = g.near_index(G, r + g.step)  # (N, E): interp < r + step
            binhit = np.zeros_like(hit)
            if near.any():
                n_i, e_i = np.nonzero(near)
                pb = P[n_i, :, e_i] @ Rb.T + tb
                binhit[n_i, e_i] = g.exact(pb) < r[e_i]
            hit |= binhit
        coll = hit.any(axis=1)
        # self-collision of non-adjacent capsule pairs (all pairs of all configurations at once)
        selfhit = None
        if len(self._pairs):
            C = _CAPS
            fc = frames[:, C.link, :3, :]  # (N, C, 3, 4)
            e0 = np.einsum("ncij,cj->nci", fc, C.p0)
            e1 = np.einsum("ncij,cj->nci", fc, C.p1)
            a, b = self._pairs[:, 0], self._pairs[:, 1]
            d = segment_distances(
                e0[:, a].reshape(-1, 3),
                e1[:, a].reshape(-1, 3),
                e0[:, b].reshape(-1, 3),
                e1[:, b].reshape(-1, 3),
            ).reshape(N, -1)
            selfhit = d < (C.radius[a] + C.radius[b])
            coll |= selfhit.any(axis=1)
        what: list[str] = []
        if explain:
            names = _SAMPLES.names
            for label, m in (("floor", floor), ("cell wall", wall), ("mobile base", box), ("bin", binhit)):
                if m is None:
                    continue
                for ci in sorted(set(E.owner[m[0]].tolist())):
                    what.append(f"{names[ci]} vs {label}")
            if selfhit is not None:
                for k in np.flatnonzero(selfhit[0]):
                    pa, pb_ = self._pairs[k]
                    what.append(f"{names[pa]} vs {names[pb_]}")
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
