"""The robot's ``wash`` op on the sim arm: sweeps run as continuous motions, the twin's powder
under the jet goes, a sweep in collision or a stop is refused like a move, and renders show it."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from cellctl.config import load_config
from cellctl.errors import RobotError
from cellctl.geometry.transforms import invert
from cellctl.messages import ApproachRequest, WashRequest, WashSweep
from cellctl.planning.robot import default_robot_model
from cellctl.sim.ground_truth import PowderField, SprayPass
from cellctl.surface import EXTERNAL
from cellctl.washing.nozzle import NozzleModel
from cellctl.washing.plan import WashParams, plan_wash
from cellctl.workers.robot import make_robot


def _spot() -> PowderField:
    """A clump on the case-study wall facing the parked robot (as tests/washing/test_plan.py)."""
    return PowderField(
        np.array([[0.2, -0.37, -0.15]]), np.array([0.04]), np.array([EXTERNAL], np.uint8), np.array([[0, -1.0, 0]]), 7
    )


@pytest.fixture(scope="module")
def parked():
    robot = make_robot(load_config(None, ["robot.speed_scale=1000", "robot.settle_s=0"]))
    robot.approach(ApproachRequest(park=True))
    sc = robot.scenario
    mesh = robot.catalog.load_mesh(sc.bin_type)
    # the supervisor plans at the measured pose; here the true one (the twin's parking error included)
    T_bin_base = invert(sc.T_world_bin(robot.catalog.get(sc.bin_type))) @ sc.base()
    field = _spot()
    dirty = field.dirty_faces(mesh)
    plan = plan_wash(
        mesh,
        {"seen_dirty": np.flatnonzero(dirty).tolist()},
        [T_bin_base],
        NozzleModel.from_config(robot.cfg.nozzle),
        default_robot_model(),
        WashParams(q_start=tuple(robot.joints)),
    )
    assert plan.moves and not plan.unwashable
    yield robot, mesh, field, plan
    robot.close()


def _request(plan, round_: int = 1) -> WashRequest:
    return WashRequest(
        sweeps=[WashSweep(joints=sw.q.tolist(), passes=sw.passes, region=sw.region) for sw in plan.sweeps],
        round=round_,
    )


def test_the_sweeps_run_and_the_twin_loses_the_powder_under_the_jet(parked) -> None:
    robot, mesh, field, plan = parked
    before = robot.sim_state().wash_passes
    reply = robot.wash(_request(plan))
    assert reply.sweeps_run == len(plan.sweeps)
    assert reply.passes_run == sum(sw.passes for sw in plan.sweeps)
    assert np.allclose(reply.joints, plan.sweeps[-1].q[-1 if plan.sweeps[-1].passes % 2 else 0], atol=1e-6)
    st = robot.sim_state(washes=True)
    assert st.wash_passes == before + reply.passes_run and len(st.washes) == st.wash_passes
    assert robot.sim_state().washes is None  # the published state stays small
    washed = PowderField(field.centres, field.radii, field.surface, field.normals, field.seed)
    for m in st.washes[before:]:
        washed.wash(SprayPass(np.asarray(m.spots), np.asarray(m.axes), m.radius, m.cos_incidence, m.removal))
    assert field.dirty_faces(mesh).sum() >= 3
    assert not washed.dirty_faces(mesh).any()  # the jet went where the plan said, on the true bin


def test_a_sweep_in_collision_is_refused_before_any_motion(parked) -> None:
    robot, *_ = parked
    q0, n0 = robot.joints.copy(), robot.sim_state().wash_passes
    inside_floor = [0.0, -0.2, 2.6, 0.0, 0.0, 0.0]  # forearm folded down through the floor
    with pytest.raises(RobotError, match=r"wash sweep 1 .* in collision"):
        robot.wash(WashRequest(sweeps=[WashSweep(joints=[q0.tolist()]), WashSweep(joints=[q0.tolist(), inside_floor])]))
    assert np.allclose(robot.joints, q0) and robot.sim_state().wash_passes == n0


def test_a_stop_interrupts_the_wash_like_a_move(parked) -> None:
    robot, _, _, plan = parked
    robot.cfg = robot.cfg.model_copy(update={"robot": robot.cfg.robot.model_copy(update={"speed_scale": 0.5})})
    try:
        n0 = robot.sim_state().wash_passes
        threading.Timer(0.3, robot.stop, args=("hold",)).start()
        with pytest.raises(RobotError, match="stopped"):
            robot.wash(_request(plan, 2))
        assert robot.sim_state().wash_passes - n0 < sum(sw.passes for sw in plan.sweeps)
    finally:
        robot.cfg = robot.cfg.model_copy(update={"robot": robot.cfg.robot.model_copy(update={"speed_scale": 1000})})


def test_a_render_after_a_full_wash_shows_no_powder() -> None:
    from cellctl.geometry.camera import CameraModel
    from cellctl.geometry.catalog import load_catalog
    from cellctl.geometry.transforms import look_at
    from cellctl.sim.render import SimRenderer
    from cellctl.sim.scene import Scenario

    cfg = load_config()
    r = SimRenderer(load_catalog(cfg.path(cfg.catalog), cfg.root))
    sc = Scenario(bin_type="tote", dirty=True, powder_amount=1.0, seed=3)
    cam = CameraModel(width=160, height=120, fx=150, fy=150, cx=80, cy=60)
    bt = r.catalog.get("tote")
    T_world_bin = sc.T_world_bin(bt)
    T_world_cam = look_at(T_world_bin[:3, 3] + np.array([0.0, -1.4, 1.2]), T_world_bin[:3, 3])
    dirty = r.render(sc, T_world_cam, cam, cell=False)
    assert dirty.powder_mask.sum() > 50
    # passes over everything from the six directions, each removing all: jets 5 m wide (bin frame)
    everything = [SprayPass(np.zeros((1, 3)), a[None], 5.0, 0.0, 1.0) for a in np.vstack([np.eye(3), -np.eye(3)])]
    washed = r.render(sc, T_world_cam, cam, cell=False, washes=everything)
    assert washed.powder_mask.sum() < 0.05 * dirty.powder_mask.sum()
    again = r.render(sc, T_world_cam, cam, cell=False)  # the cached field itself was not washed
    assert again.powder_mask.sum() == dirty.powder_mask.sum()
