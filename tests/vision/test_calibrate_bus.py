"""`cellctl calibrate hand-eye` over real Zenoh: robot and camera doubles render the board."""

from __future__ import annotations

import json
import threading

import cv2
import numpy as np
import pytest
import yaml

from cellctl.bus.session import open_session
from cellctl.errors import RobotError
from cellctl.geometry.transforms import invert, look_at, pose_error, transform_from_xyz_rpy
from cellctl.messages import (
    CaptureReply,
    CaptureRequest,
    MoveReply,
    MoveRequest,
    PoseMsg,
    RobotState,
    RobotStateRequest,
)
from cellctl.vision.collect import collect_hand_eye
from cellctl.vision.render import render_boards
from cellctl.workers._server import WorkerServer

from .scenes import INTR, SPEC_A

X_TRUE = transform_from_xyz_rpy((0.06, -0.015, 0.09), (0.02, -0.03, np.pi / 2))
X_MODEL = transform_from_xyz_rpy((0.055, -0.01, 0.095), (0.0, 0.0, np.pi / 2))  # the robot's nominal guess
T_BASE_BOARD = transform_from_xyz_rpy((1.1, 0.2, 0.5), (-np.pi / 2, 0.0, np.pi / 2))


class SimArmCamera:
    """A robot that moves by its nominal hand-eye model and a camera that sees by the true one."""

    def __init__(self, session, cell_id: str, unreachable: set[int]) -> None:
        c = T_BASE_BOARD[:3, :3] @ np.array([0.21, 0.15, 0.0]) + T_BASE_BOARD[:3, 3]
        self.flange = look_at(c + 0.7 * -T_BASE_BOARD[:3, 2], c) @ invert(X_MODEL)
        self.moves = 0
        self.unreachable = unreachable
        self.rng = np.random.default_rng(0)
        self.lock = threading.Lock()
        self.robot = WorkerServer(session, cell_id, "robot")
        self.camera = WorkerServer(session, cell_id, "camera")
        self.robot.serve("move", MoveRequest, self._move)
        self.robot.serve("state", RobotStateRequest, self._state)
        self.camera.serve("capture", CaptureRequest, self._capture)

    def _pose(self) -> PoseMsg:
        return PoseMsg.from_matrix(self.flange @ X_MODEL)

    def _move(self, req: MoveRequest, _: bytes | None) -> MoveReply:
        with self.lock:
            self.moves += 1
            if self.moves in self.unreachable:
                raise RobotError(f"camera pose {req.camera_pose.position} is out of reach")
            if req.camera_pose is not None:
                self.flange = req.camera_pose.matrix() @ invert(X_MODEL)
            return MoveReply(joints=[0.0] * 6, camera_pose=self._pose())

    def _state(self, req: RobotStateRequest, _: bytes | None) -> RobotState:
        with self.lock:
            return RobotState(joints=[0.0] * 6, flange_pose=PoseMsg.from_matrix(self.flange), camera_pose=self._pose())

    def _capture(self, req: CaptureRequest, _: bytes | None) -> tuple[CaptureReply, bytes]:
        with self.lock:
            T_cam_board = invert(self.flange @ X_TRUE) @ T_BASE_BOARD
            img = render_boards([(SPEC_A, T_cam_board)], INTR, rng=self.rng)
        ok, buf = cv2.imencode(".png", img)
        assert ok
        return CaptureReply(format="png", intrinsics=INTR, camera_pose=self._pose()), buf.tobytes()

    def close(self) -> None:
        self.robot.close()
        self.camera.close()


@pytest.fixture
def sim(cfg):
    router = open_session(cfg, "router")
    workers = open_session(cfg, "client")
    s = SimArmCamera(workers, cfg.cell_id, unreachable={3})
    yield s
    s.close()
    workers.close()
    router.close()


def test_collect_and_solve_over_zenoh(cfg, sim, catalog) -> None:
    with open_session(cfg, "client") as session:
        result, views, skipped = collect_hand_eye(session, cfg, catalog, n_views=8, seed=1, progress=False)
    assert len(views) == 7 and len(skipped) == 1 and "out of reach" in skipped[0]
    dt, dr = pose_error(result.T_flange_cam, X_TRUE)
    assert dt * 1000 < 1.0 and np.degrees(dr) < 0.1
    # The nominal model was 7 mm off: the calibration is what fixes it.
    assert pose_error(X_MODEL, X_TRUE)[0] * 1000 > 5


def test_cli_writes_calibration(cfg, sim, tmp_path) -> None:
    from cellctl.cli import main

    out = tmp_path / "he.json"
    bins = tmp_path / "bins.yaml"
    bins.write_text(
        yaml.safe_dump(
            {
                "bins": {
                    "bench_bin": {
                        "mesh": "models/bins/none.ply",
                        "mesh_sha256": "0" * 64,
                        "height_m": 1.0,
                        "top_hole_radius_m": 0.25,
                        "board": {
                            "squares_x": 7,
                            "squares_y": 5,
                            "square_m": 0.06,
                            "marker_m": 0.045,
                            "first_id": 0,
                            "T_bin_board": np.eye(4).tolist(),
                        },
                    }
                }
            }
        )
    )
    ep = cfg.bus.connect[0]
    rc = main(
        [
            "calibrate",
            "hand-eye",
            "--views",
            "6",
            "--out",
            str(out),
            "--catalog",
            str(bins),
            "--set",
            f'bus.connect=["{ep}"]',
        ]
    )
    assert rc == 0
    data = json.loads(out.read_text())
    assert data["type"] == "cellctl/HandEyeCalibration" and data["method"] == "park-martin"
    T = np.array(data["T_flange_cam_matrix"])
    dt, dr = pose_error(T, X_TRUE)
    assert dt * 1000 < 1.5 and np.degrees(dr) < 0.15
