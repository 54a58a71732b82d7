"""Wash sweeps the arm can get to: every sweep is joined to the arm's home by straight collision-free
joint motions (the inspection planner's connection), so the robot, which plans a sweep it cannot
move straight to through home, is never handed a flipped arm shape no planner connects; and the
powder on a long sliver of a face is washed where it lies, not only at the face's corners.

The case is the demo's wash story (cycle 3 at f281124, round 3): one dirty face, 4365, a 145 cm²
sliver of the outside wall beside the powder clump at (-0.43, 0.335, -0.585), planned from the four
stations the scan used (their measured poses and the arm's joints, as logged). The planner gave it
one sweep with the shoulder at +3.03 rad that the arm refused every round ("no collision-free path
from home … within 3 s (RRTConnect)") and the cycle failed: "robot ran none of the 1 wash sweeps".
The powder there is the edge of the demo's clump at (-0.43, 0.335, -0.585) (scenario seed 18).
"""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.config import load_config
from cellctl.geometry.catalog import load_catalog
from cellctl.messages import PoseMsg
from cellctl.planning.collision import PlanningWorld
from cellctl.planning.robot import default_robot_model
from cellctl.washing.nozzle import NozzleModel
from cellctl.washing.plan import WashParams, plan_wash
from cellctl.washing.twin import wash_in_twin

# T_bin_base of the four stations (position, quaternion xyzw), as the round-3 WashPlanRequest had them
STATIONS = [
    ((-1.19387, 0.10265, -0.32999), (0.000285, -0.0000997, -0.0341276, 0.9994174)),
    ((1.01314, 0.85926, -0.32768), (0.000339, 0.00082, -0.9375757, 0.3477802)),
    ((0.09521, 1.15979, -0.32721), (0.00063, 0.000624, -0.7295842, 0.6838905)),
    ((-0.08222, -1.13887, -0.33172), (0.000593, -0.001028, 0.6808911, 0.7323837)),
]
Q_START = (3.24982, 0.05246, 1.79634, -2.82052, 1.59287, -3.17490)
FACE = 4365
STEP = 0.02  # the connection's check step (cellctl.planning.whole.COARSE_STEP_RAD)


@pytest.fixture(scope="module")
def setup():
    cfg = load_config()
    mesh = load_catalog(cfg.path(cfg.catalog), cfg.root).load_mesh("case_study")
    nozzle = NozzleModel.from_config(cfg.nozzle)
    robot = default_robot_model()
    poses = [PoseMsg(position=p, orientation=q, frame_id="bin").matrix() for p, q in STATIONS]
    return mesh, nozzle, robot, poses


def _joined_to_home(plan, mesh, nozzle, robot) -> list[bool]:
    """Per sweep: is one of its ends joined to home by straight free motions through the plan's own waypoints?"""
    tool = nozzle.robot_with_nozzle(robot)
    out = []
    for k in sorted({sw.station for sw in plan.sweeps}):
        world = PlanningWorld(mesh, tool, plan.stations[k], margin=0.005)
        mine = [i for i, sw in enumerate(plan.sweeps) if sw.station == k]
        Q = np.vstack([plan.sweeps[i].q for i in mine])
        owner = np.concatenate([np.full(len(plan.sweeps[i].q), i) for i in mine])
        joined = world.motion_free(np.repeat(robot.q_home[None], len(Q), axis=0), Q, STEP)
        for _ in range(len(Q)):  # grow through the plan's waypoints until nothing more joins
            todo, done = np.flatnonzero(~joined), np.flatnonzero(joined)
            if not len(todo) or not len(done):
                break
            A = np.repeat(Q[todo], len(done), axis=0)
            B = np.tile(Q[done], (len(todo), 1))
            new = world.motion_free(A, B, STEP).reshape(len(todo), len(done)).any(axis=1)
            if not new.any():
                break
            joined[todo[new]] = True
        out += [(i, bool(joined[owner == i].any())) for i in mine]
    return [ok for _, ok in sorted(out)]


def test_a_flipped_sweep_no_planner_connects_is_not_planned(setup) -> None:
    """The sliver's only sweep was a flipped shoulder no motion from home reaches: every sweep planned
    now is joined to home; the face's far corner (near the floor) stays out of reach, so it is reported
    unwashable with why (a plan with no sweep names it in its reason: the cycle ends dirty, naming it)."""
    mesh, nozzle, robot, poses = setup
    params = WashParams(threshold=0.5, margin_m=0.02, q_start=Q_START, cpu_budget_s=60.0)
    plan = plan_wash(mesh, {"seen_dirty": [FACE]}, poses, nozzle, robot, params)
    joined = _joined_to_home(plan, mesh, nozzle, robot)
    assert all(joined), [np.round(sw.q[0], 2).tolist() for sw, ok in zip(plan.sweeps, joined, strict=True) if not ok]
    assert any(FACE in u.faces for u in plan.unwashable)
    if not plan.sweeps:  # the reason names the piece: its size, surface, where, its face
        assert "145 cm² of the external surface at (-413, 310, -643) mm, faces 4365" in plan.reason, plan.reason


def test_every_sweep_of_the_first_round_is_joined_to_home(setup) -> None:
    """The first round's dirt (the five clumps, dilated): the sweeps the arm could already get to are
    still planned, and no sweep is left that only a flipped arm shape reaches."""
    mesh, nozzle, robot, poses = setup
    clumps = [2052, 2053, 2054, 2116, 2117, 2181, 2182, 2237, 2238, 2239, 2244, 2245, 2246, 2301, 2302, 2310]
    clumps += [2366, 2367, 2373, 2374, 2429, 2430, 2431, 3114, FACE]
    plan = plan_wash(mesh, {"seen_dirty": clumps}, poses, nozzle, robot, WashParams(q_start=Q_START))
    assert len(plan.sweeps) >= 10
    joined = _joined_to_home(plan, mesh, nozzle, robot)
    assert all(joined), [np.round(sw.q[0], 2).tolist() for sw, ok in zip(plan.sweeps, joined, strict=True) if not ok]
    assert plan.summary(mesh)["covered_m2"] > 0.8 * float(mesh.areas[plan.targets].sum()) - 0.0145


def test_the_powder_on_the_sliver_is_washed_by_the_sweeps_the_arm_can_get_to(setup) -> None:
    """The sweeps of the round-3 plan that are joined to home, run in the twin over the demo's powder,
    leave under a fifth of the clump's edge on the sliver (sampled where the clump lies on the face).
    Before the demand points lay along long faces, the one sweep aimed at the face's centroid and
    corners; this checks the powder, not where the sweeps aim."""
    from dataclasses import replace

    from cellctl.sim.ground_truth import PowderField

    mesh, nozzle, robot, poses = setup
    params = WashParams(threshold=0.5, margin_m=0.02, q_start=Q_START, cpu_budget_s=60.0)
    plan = plan_wash(mesh, {"seen_dirty": [FACE]}, poses, nozzle, robot, params)
    joined = _joined_to_home(plan, mesh, nozzle, robot)
    runnable = replace(plan, sweeps=tuple(sw for sw, ok in zip(plan.sweeps, joined, strict=True) if ok))
    field = PowderField.sample(mesh, 0.01, 18)
    clump = int(np.argmin(np.linalg.norm(field.centres - [-0.43, 0.335, -0.585], axis=1)))
    V = mesh.vertices[mesh.faces[FACE]]
    u = np.random.default_rng(0).random((4000, 2))
    u = u[u.sum(axis=1) <= 1]
    P = V[0] + u[:, :1] * (V[1] - V[0]) + u[:, 1:] * (V[2] - V[0])
    P = P[np.linalg.norm(P - field.centres[clump], axis=1) <= field.radii[clump]]  # the powder on the sliver
    assert len(P) > 50
    wash_in_twin(field, runnable, mesh, nozzle)
    left = field.remaining(P, np.repeat(mesh.normals[FACE][None], len(P), axis=0))
    assert left.mean() < 0.2, (len(runnable.sweeps), float(left.mean()))
