"""``robot.hand_eye``: the controller uses the calibrated ``T_flange_cam``; the twin keeps the physical mount."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cellctl.app import preflight
from cellctl.config import CellConfig, load_config
from cellctl.errors import ConfigError
from cellctl.geometry import robot_model as rm
from cellctl.geometry.transforms import pose_error, transform_from_xyz_rpy
from cellctl.planning.robot import RobotModel, default_robot_model
from cellctl.sim import scene
from cellctl.vision.handeye import HandEyeResult, configured_hand_eye

# The estimate differs from the nominal mount by 4 mm and 1.5°: a plausible calibration.
T_HE = rm.T_FLANGE_CAM @ transform_from_xyz_rpy((0.004, -0.002, 0.001), (np.radians(1.5), 0.0, 0.0))


def write_hand_eye(path: Path, T: np.ndarray) -> Path:
    """The file as `cellctl calibrate hand-eye` writes it (HandEyeResult.to_dict)."""
    r = HandEyeResult(
        T_flange_cam=T, T_base_board=np.eye(4), residual_mm=[0.3], residual_deg=[0.05], n_views=8, axis_spread_deg=80
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"type": "cellctl/HandEyeCalibration", **r.to_dict()}))
    return path


def cell_with(tmp_path: Path, hand_eye: str) -> Path:
    p = tmp_path / "config" / "cell.yaml"  # root = tmp_path: relative paths resolve like the others
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(f"robot:\n  hand_eye: {hand_eye}\n")
    return p


def test_default_config_has_no_hand_eye_and_the_nominal_model() -> None:
    cfg = load_config()
    assert cfg.robot.hand_eye is None and configured_hand_eye(cfg) is None
    assert RobotModel.from_config(cfg).model_id() == default_robot_model().model_id()


def test_a_relative_hand_eye_file_is_loaded_and_the_planner_model_carries_it(tmp_path: Path) -> None:
    write_hand_eye(tmp_path / "models" / "calibration" / "hand_eye.json", T_HE)
    cfg = load_config(cell_with(tmp_path, "models/calibration/hand_eye.json"))
    assert np.allclose(configured_hand_eye(cfg), T_HE)
    robot = RobotModel.from_config(cfg)
    assert np.allclose(robot.T_flange_cam, T_HE)
    assert robot.model_id() != default_robot_model().model_id()  # plans for the old mount become cache misses
    q = scene.HOME_JOINTS
    assert np.allclose(robot.fk_cam(q[None])[0], rm.fk(q) @ T_HE)


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "does not exist"),
        ("{not json", "not valid JSON"),
        ('{"T_flange_cam": {}}', "expected an object with key 'T_flange_cam_matrix'"),
        ('{"T_flange_cam_matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}', "must have shape (4, 4), got (3, 3)"),
        (
            json.dumps({"T_flange_cam_matrix": (np.diag([1.0, 1.0, -1.0, 1.0])).tolist()}),
            "rotation part is not a proper rotation",
        ),
        (
            json.dumps({"T_flange_cam_matrix": transform_from_xyz_rpy((118.0, 58.0, -35.0), (0, 0, 0)).tolist()}),
            "m from the flange, expected at most 0.5 m",
        ),
    ],
)
def test_a_bad_hand_eye_file_is_a_config_error_naming_it(tmp_path: Path, content: str | None, message: str) -> None:
    he = tmp_path / "he.json"
    if content is not None:
        he.write_text(content)
    with pytest.raises(ConfigError) as e:  # the check `validate` and `run` make (cellctl.config reads no file)
        preflight(load_config(cell_with(tmp_path, str(he))))
    assert "robot.hand_eye" in str(e.value) and str(he) in str(e.value)
    assert message in str(e.value)


def test_the_robot_worker_reports_and_targets_camera_poses_with_the_calibration(
    tmp_path: Path, cfg: CellConfig
) -> None:
    from cellctl.messages import MoveRequest, PoseMsg
    from cellctl.workers.robot._sim import SimRobot

    cfg.robot.hand_eye = write_hand_eye(tmp_path / "he.json", T_HE)
    cfg.robot.speed_scale = 50.0
    robot = SimRobot(cfg)
    try:
        q0 = robot.joints
        assert np.allclose(robot.state().camera_pose.matrix(), rm.fk(q0) @ T_HE, atol=1e-9)
        target = rm.camera_pose(q0 + np.array([0.0, 0.1, -0.15, 0.05, 0.0, 0.1]), T_HE)
        reply = robot.move(MoveRequest(camera_pose=PoseMsg.from_matrix(target), settle_s=0))
        q = np.asarray(reply.joints)
        dt, dr = pose_error(target, rm.fk(q) @ T_HE)  # the calibrated camera is where it was sent
        assert dt < 1e-6 and dr < 1e-6
        assert np.allclose(reply.camera_pose.matrix(), target, atol=1e-6)
        # the twin's physical camera (nominal mount) is off by the calibration's difference
        assert pose_error(target, rm.camera_pose(q))[0] > 0.003
    finally:
        robot.close()
