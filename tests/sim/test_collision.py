"""Batch collision checks: bin, floor, mobile base, self; grid vs exact; batch vs single; pybullet."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.config import project_root
from cellctl.geometry import robot_model as rm
from cellctl.geometry.catalog import load_catalog
from cellctl.geometry.transforms import invert
from cellctl.sim import scene
from cellctl.sim.collision import CollisionWorld, segment_distances


@pytest.fixture(scope="module")
def setup():
    cat = load_catalog(project_root() / "config" / "bins.yaml")
    bt, mesh = cat.get("case_study"), cat.load_mesh("case_study")
    sc = scene.Scenario("case_study")
    sc = sc.with_base(scene.park(sc, bt, mesh, 0.0, 0.0))
    world = CollisionWorld(mesh, invert(sc.base()) @ sc.T_world_bin(bt), invert(sc.base()))
    return cat, bt, mesh, sc, world


def test_home_is_free_and_obvious_collisions_are_named(setup) -> None:
    _, bt, mesh, sc, world = setup
    assert world.explain(scene.HOME_JOINTS) == []
    # shoulder lift pointing the arm down through the mobile base / floor
    down = np.array([np.pi, 0.9, 0.0, 0.0, 0.0, 0.0])
    hits = world.explain(down)
    assert any("mobile base" in h or "floor" in h for h in hits), hits
    # camera placed on the bin wall: every IK solution hits the bin
    T_base_bin = invert(sc.base()) @ sc.T_world_bin(bt)
    T_bin_cam = np.eye(4)
    T_bin_cam[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]
    T_bin_cam[:3, 3] = [0.0, -0.37, -0.2]
    sols = rm.ik_camera(T_base_bin @ T_bin_cam)
    assert len(sols) > 0
    for s in sols:
        assert "camera vs bin" in world.explain(s)


def test_batch_equals_single_calls(setup) -> None:
    *_, world = setup
    rng = np.random.default_rng(0)
    Q = rng.uniform(-np.pi, np.pi, (300, 6))
    batch = world.check(Q)
    single = np.array([world.in_collision(q) for q in Q])
    assert np.array_equal(batch, single)
    assert 0.05 < batch.mean() < 0.95


def test_distance_grid_agrees_with_exact_distances(setup) -> None:
    _, _, mesh, _, world = setup
    rng = np.random.default_rng(1)
    lo, hi = mesh.vertices.min(0) - 0.1, mesh.vertices.max(0) + 0.1
    P = rng.uniform(lo, hi, (3000, 3))
    g, e = world.grid.interp(P), world.grid.exact(P)
    near = e < world.grid.pad - 0.02
    assert np.abs(g[near] - e[near]).max() < world.grid.step  # trilinear error < one cell


def test_segment_distances_match_brute_force() -> None:
    rng = np.random.default_rng(2)
    p0, p1, q0, q1 = rng.normal(size=(4, 200, 3))
    d = segment_distances(p0, p1, q0, q1)
    s = np.linspace(0, 1, 401)
    for i in range(0, 200, 20):
        a = p0[i] + s[:, None] * (p1[i] - p0[i])
        b = q0[i] + s[:, None] * (q1[i] - q0[i])
        brute = np.linalg.norm(a[:, None] - b[None], axis=2).min()
        assert d[i] == pytest.approx(brute, abs=5e-3)
        assert d[i] <= brute + 1e-9


def test_pybullet_world_agrees_with_the_fast_checker(setup) -> None:
    """The pybullet (DIRECT) twin and the grid checker agree except within a few mm of contact."""
    from cellctl.sim.pybullet_world import PyBulletWorld

    cat, bt, mesh, sc, world = setup
    pb = PyBulletWorld(mesh, world.T_base_bin, world.T_base_world)
    try:
        rng = np.random.default_rng(3)
        Q = rng.uniform(-np.pi, np.pi, (150, 6))
        fast = world.check(Q)
        slow = np.array([pb.in_collision(q) for q in Q])
        loose = CollisionWorld(mesh, world.T_base_bin, world.T_base_world, margin=0.03).check(Q)
        tight = CollisionWorld(mesh, world.T_base_bin, world.T_base_world, margin=-0.02).check(Q)
        # anything pybullet calls a collision, the fast checker with a 3 cm margin does too, and
        # anything the fast checker (2 cm tighter) calls a collision, pybullet does too
        assert not (slow & ~loose).any()
        assert not (tight & ~slow).any()
        assert (fast == slow).mean() > 0.9
    finally:
        pb.close()


def _plain_bin_env_hits(world: CollisionWorld, Q: np.ndarray) -> np.ndarray:
    """The bin/floor/wall/box part of the check written plainly (every sphere, :meth:`interp`)."""
    from cellctl.sim.collision import _SAMPLES

    S = _SAMPLES
    frames = rm.link_frames(Q)
    pts = np.einsum("nsij,sj->nsi", frames[:, S.link], S.local)[..., :3]
    r = S.radius + world.margin
    pw = pts @ world._T_world_base[:3, :3].T + world._T_world_base[:3, 3]
    hit = pw[..., 2] < r
    hit |= (np.abs(pw[..., 0]) > world.walls[0] - r) | (np.abs(pw[..., 1]) > world.walls[1] - r)
    d_box = np.linalg.norm(np.maximum(np.maximum(world._box_lo - pts, pts - world._box_hi), 0.0), axis=-1)
    hit |= (d_box < r) & (S.link[None, :] >= 2)
    pb = (pts @ world._T_bin_base[:3, :3].T + world._T_bin_base[:3, 3]).reshape(-1, 3)
    rr = np.broadcast_to(r, hit.shape).reshape(-1)
    near = world.grid.interp(pb) < rr + world.grid.step
    binhit = np.zeros(len(pb), dtype=bool)
    binhit[near] = world.grid.exact(pb[near]) < rr[near]
    hit |= binhit.reshape(hit.shape)
    return (hit & S.env).any(axis=1)


def test_fast_check_equals_the_plain_formulation(setup) -> None:
    """The block-minimum broad phase and the per-link sphere transforms change no flag.

    Configurations from everywhere in joint space and (the hard case) camera poses at 2-12 cm
    from the bin surface, where the trilinear lookup and the exact re-check decide.
    """
    from cellctl.sim.collision import COARSE_BLOCK, _block_min

    _, bt, mesh, sc, world = setup
    rng = np.random.default_rng(3)
    Q = rng.uniform(-np.pi, np.pi, (3000, 6))
    T_base_bin = invert(sc.base()) @ sc.T_world_bin(bt)
    near_q = []
    for f in rng.choice(len(mesh.faces), 400, replace=False):
        c = mesh.vertices[mesh.faces[f]].mean(axis=0)
        n = np.cross(*(mesh.vertices[mesh.faces[f]][1:] - mesh.vertices[mesh.faces[f]][0]))
        n /= np.linalg.norm(n) + 1e-12
        T = np.eye(4)
        T[:3, 2] = -n  # looking at the face from its normal side
        x = np.cross([0.0, 0.0, 1.0], T[:3, 2])
        if np.linalg.norm(x) < 1e-6:
            x = np.array([1.0, 0.0, 0.0])
        T[:3, 0] = x / np.linalg.norm(x)
        T[:3, 1] = np.cross(T[:3, 2], T[:3, 0])
        T[:3, 3] = c + n * rng.uniform(0.02, 0.12)
        near_q.extend(rm.ik_camera(T_base_bin @ T))
    Q = np.vstack([Q, np.array(near_q).reshape(-1, 6)])
    assert len(Q) > 3500
    fast = world.check(Q)
    plain_env = _plain_bin_env_hits(world, Q)
    # the fast check = plain environment hits OR self-collision; where plain says hit, so does fast
    assert np.all(fast[plain_env])
    only_fast = fast & ~plain_env
    for q in Q[only_fast][:200]:  # every extra flag is a self-collision, nothing else
        assert all(h.split(" vs ")[1] not in {"floor", "cell wall", "mobile base", "bin"} for h in world.explain(q))
    assert 0.05 < plain_env.mean() < 0.95
    # the block minimum bounds every trilinear value from below
    g = world.grid
    bm = _block_min(g.grid, COARSE_BLOCK)
    P = rng.uniform(g.lo, g.lo + g.step * (np.array(g.shape) - 1), (20000, 3))
    idx = ((P - g.lo) / g.step).astype(int) // COARSE_BLOCK
    assert np.all(bm[idx[:, 0], idx[:, 1], idx[:, 2]] <= g.interp(P) + 1e-7)
