"""``cellctl bench sim``: IK per pose, collision check per configuration, render per frame.

Everything runs on the case-study bin parked as in a cycle. Figures are medians of
repeated timings (``--n`` poses/configurations, default 2000).
"""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np

from cellctl.bench.options import BenchOptions

__all__ = ["bench_sim"]


def _median_time(fn, reps: int) -> float:
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def bench_sim(opts: BenchOptions) -> dict[str, Any]:
    """``opts.n`` random configurations (default 2000) drawn from ``opts.seed``."""
    from tqdm import tqdm
    from ur_analytic_ik import ur10e

    from cellctl.geometry import robot_model as rm
    from cellctl.geometry.camera import D435_COLOR
    from cellctl.geometry.catalog import load_catalog
    from cellctl.geometry.transforms import invert
    from cellctl.sim import scene
    from cellctl.sim.collision import CollisionWorld
    from cellctl.sim.motion import plan_path
    from cellctl.sim.render import SimRenderer

    n = opts.n or 2000
    rng = np.random.default_rng(opts.seed)
    cfg = opts.load_config()
    cat = load_catalog(cfg.path(cfg.catalog))
    bt = cat.get("case_study")
    mesh = cat.load_mesh("case_study")
    sc = scene.Scenario("case_study", dirty=True, seed=opts.seed)
    sc = sc.with_base(scene.park(sc, bt, mesh, 0.03, 2.0, 1))
    t0 = time.perf_counter()
    world = CollisionWorld(mesh, invert(sc.base()) @ sc.T_world_bin(bt), invert(sc.base()))
    world_init_s = time.perf_counter() - t0
    Q = rng.uniform(rm.JOINT_LIMITS[:, 0], rm.JOINT_LIMITS[:, 1], (n, 6))
    Q[:, 2] = rng.uniform(-np.pi, np.pi, n)
    poses = rm.fk_batch(Q)
    bar = tqdm(total=6, desc="bench sim", file=sys.stderr)
    # IK: the raw analytic solver and cellctl's wrapper (limits, 2π wrapping, sorting)
    raw = _median_time(lambda: [ur10e.inverse_kinematics(T) for T in poses[:200]], 5) / 200
    bar.update()
    wrapped = _median_time(lambda: [rm.ik(T, Q[0]) for T in poses[:200]], 3) / 200
    many = _median_time(lambda: rm.ik_many(poses[:200], Q[0]), 3) / 200
    n_sol = float(np.mean([len(rm.ik(T)) for T in poses[:200]]))
    bar.update()
    # FK round trip
    err = 0.0
    for T in poses[:500]:
        S = rm.ik(T)
        if len(S):
            err = max(err, float(np.abs(rm.fk_batch(S)[:, :3, 3] - T[:3, 3]).max()))
    bar.update()
    # collisions: one batch of n configurations, and single calls
    world.check(Q[:10])
    batch = _median_time(lambda: world.check(Q), 3) / n
    single = _median_time(lambda: [world.in_collision(q) for q in Q[:200]], 3) / 200
    frac = float(world.check(Q).mean())
    bar.update()
    # a motion: home → observation pose 0
    T_cam = invert(scene.nominal_T_bin_base(bt, mesh)) @ scene.observation_T_bin_cam(bt, 0)
    goal = next(q for q in rm.ik_camera(T_cam, scene.HOME_JOINTS) if not world.in_collision(q))
    plan = _median_time(lambda: plan_path(world, scene.HOME_JOINTS, goal), 3)
    bar.update()
    # render
    r = SimRenderer(cat)
    q = goal
    T_world_cam = sc.base() @ rm.camera_pose(q)
    r.render(sc, T_world_cam, D435_COLOR.scaled(0.25), joints=q)
    full = _median_time(lambda: r.render(sc, T_world_cam, D435_COLOR, joints=q), 3)
    low = _median_time(lambda: r.render(sc, T_world_cam, D435_COLOR.scaled(0.25), joints=q), 5)
    bar.update()
    bar.close()
    return {
        "ik_us_per_pose": round(wrapped * 1e6, 1),
        "ik_raw_us_per_pose": round(raw * 1e6, 2),
        "ik_many_us_per_pose": round(many * 1e6, 1),
        "ik_solutions_mean": round(n_sol, 2),
        "ik_fk_roundtrip_max_m": err,
        "collision_us_per_config": round(batch * 1e6, 2),
        "collision_us_single_call": round(single * 1e6, 1),
        "collision_fraction_random": round(frac, 3),
        "collision_world_init_s": round(world_init_s, 3),
        "plan_home_to_observation_ms": round(plan * 1e3, 2),
        "render_ms_1280x720": round(full * 1e3, 1),
        "render_ms_320x180": round(low * 1e3, 1),
        "n_configs": n,
        "load_average_1min": round(__import__("os").getloadavg()[0], 2),
        "mesh_faces": mesh.n_faces,
    }
