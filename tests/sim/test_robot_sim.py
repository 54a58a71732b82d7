"""The sim robot: 100 random reachable camera poses around the case-study bin reached without
collision, refusals with reasons, observation poses, stop."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from cellctl.config import CellConfig, load_config
from cellctl.errors import RobotError
from cellctl.geometry import robot_model as rm
from cellctl.geometry.transforms import invert, look_at, pose_error
from cellctl.messages import ApproachRequest, MoveRequest, PoseMsg, SimScenarioRequest
from cellctl.sim import scene
from cellctl.workers.robot import make_robot


def _cfg(*extra: str) -> CellConfig:
    return load_config(None, ["robot.speed_scale=1000", "robot.settle_s=0", *extra])


@pytest.fixture(scope="module")
def robot():
    r = make_robot(_cfg())
    r.approach(ApproachRequest(park=True))
    return r


def _random_views(robot, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Camera poses (base frame) 0.25–0.55 m off random bin surface points facing the robot,
    looking at them, kept when an IK solution is collision-free (= reachable)."""
    mesh = robot.catalog.load_mesh("case_study")
    T_base_bin = invert(robot.scenario.base()) @ robot.scenario.T_world_bin(robot.catalog.get("case_study"))
    normals, cents = mesh.normals, mesh.centroids
    out = []
    while len(out) < n:
        f = rng.integers(mesh.n_faces)
        d = rng.uniform(0.25, 0.55)
        eye_bin = cents[f] + d * normals[f]
        eye = T_base_bin[:3, :3] @ eye_bin + T_base_bin[:3, 3]
        tgt = T_base_bin[:3, :3] @ cents[f] + T_base_bin[:3, 3]
        if abs((tgt - eye)[2]) / d > 0.98:  # look_at needs a horizontal component for 'up'
            continue
        # views a planner would pick: the surface faces the robot, the camera is 0.3 m above the floor
        n_base = T_base_bin[:3, :3] @ normals[f]
        if n_base @ (-tgt) / np.linalg.norm(tgt) < 0.2 or eye[2] < 0.3 - rm.BASE_HEIGHT_M:
            continue
        T = look_at(eye, tgt)
        sols = rm.ik_camera(T, robot.joints)
        if len(sols) and (~robot.world.check(sols)).any():
            out.append(T)
    return out


def test_hundred_random_reachable_camera_poses_are_reached_without_collision(robot) -> None:
    rng = np.random.default_rng(7)
    views = _random_views(robot, rng, 100)
    reached = 0
    for T in views:
        rep = robot.move(MoveRequest(camera_pose=PoseMsg.from_matrix(T)))
        dt, dr = pose_error(rep.camera_pose.matrix(), T)
        assert dt < 1e-6 and dr < 1e-6
        assert np.abs(np.asarray(rep.joints) - robot.joints).max() == 0
        # the path actually driven is collision-free at 5 mm-ish resolution (0.004 rad steps)
        assert robot.world.path_free(robot.last_path, step=0.004)
        reached += 1
    assert reached == 100


def test_unreachable_targets_are_refused_with_a_reason(robot) -> None:
    far = np.eye(4)
    far[:3, 3] = [2.8, 0.0, 0.5]
    with pytest.raises(RobotError, match=r"unreachable: wrist centre is .* m from the shoulder, beyond"):
        robot.move(MoveRequest(camera_pose=PoseMsg.from_matrix(far)))
    # a pose inside the bin wall: IK exists, every solution collides
    T_base_bin = invert(robot.scenario.base()) @ robot.scenario.T_world_bin(robot.catalog.get("case_study"))
    T_bin_cam = np.eye(4)
    T_bin_cam[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]
    T_bin_cam[:3, 3] = [0.0, -0.37, -0.2]
    with pytest.raises(RobotError, match=r"unreachable without collision: all \d IK solutions collide.*camera vs bin"):
        robot.move(MoveRequest(camera_pose=PoseMsg.from_matrix(T_base_bin @ T_bin_cam)))
    with pytest.raises(RobotError, match="frame_id is 'world'; expected 'base'"):
        robot.move(MoveRequest(camera_pose=PoseMsg(position=(0.5, 0, 0.5), frame_id="world")))
    with pytest.raises(RobotError, match="target joints .* in collision: .*mobile base"):
        robot.move(MoveRequest(joints=[np.pi, 0.9, 0.0, 0.0, 0.0, 0.0]))
    with pytest.raises(RobotError, match="joint elbow"):
        robot.move(MoveRequest(joints=[0, -1.5, 4.0, 0, 0, 0]))
    with pytest.raises(RobotError, match="observation_index 40 is out of range"):
        robot.approach(ApproachRequest(observation_index=40, park=False))


def test_observation_poses_see_the_board_for_every_bin_type() -> None:
    """After parking (with error), observation pose 0 is reachable and the board is in view."""
    r = make_robot(_cfg())
    for name in ("case_study", "drum", "tote"):
        r.set_scenario(SimScenarioRequest(bin_type=name, seed=5))
        rep = r.approach(ApproachRequest(park=True))
        bt = r.catalog.get(name)
        T_base_cam = rep.camera_pose.matrix()
        T_cam_board = invert(T_base_cam) @ invert(r.scenario.base()) @ r.scenario.T_world_bin(bt) @ bt.T_bin_board()
        w, h = bt.board.size_m
        K = np.array([[920.0, 0, 640], [0, 920.0, 360], [0, 0, 1]])
        corners = T_cam_board @ np.array([[0, 0, 0, 1], [w, 0, 0, 1], [w, h, 0, 1], [0, h, 0, 1]], float).T
        assert (corners[2] > 0.2).all()
        uv = (K @ corners[:3])[:2] / corners[2]
        assert ((uv[0] > 0) & (uv[0] < 1280) & (uv[1] > 0) & (uv[1] < 720)).all(), (name, uv)
        assert not rm.view_blocked(rep.joints)


def test_stop_interrupts_a_motion() -> None:
    r = make_robot(_cfg("robot.speed_scale=0.5"))
    r._parked = True  # move in place, no parking drive
    target = scene.HOME_JOINTS + np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    errors: list[Exception] = []

    def go() -> None:
        try:
            r.move(MoveRequest(joints=target.tolist()))
        except RobotError as err:
            errors.append(err)

    t = threading.Thread(target=go)
    t.start()
    time.sleep(0.3)
    assert r.state().moving
    r.stop("test")
    t.join(5)
    assert errors and "motion stopped (test)" in str(errors[0])
    q = r.joints
    assert 0 < q[0] - scene.HOME_JOINTS[0] < 1.0  # stopped part-way
    with pytest.raises(RobotError, match="busy"):
        r._busy.acquire()
        try:
            r.move(MoveRequest(joints=target.tolist()))
        finally:
            r._busy.release()
