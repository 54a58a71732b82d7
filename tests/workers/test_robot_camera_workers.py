"""Robot and camera workers over real Zenoh (router + client sessions on loopback)."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.bus import keys
from cellctl.bus.codec import decode_as
from cellctl.bus.rpc import request
from cellctl.bus.session import open_session
from cellctl.config import CellConfig, load_config
from cellctl.errors import WorkerFailed
from cellctl.geometry.transforms import pose_error
from cellctl.messages import (
    ApproachReply,
    ApproachRequest,
    CaptureReply,
    CaptureRequest,
    JointState,
    MoveReply,
    MoveRequest,
    PoseMsg,
    RobotState,
    RobotStateRequest,
    SimScenarioRequest,
    SimState,
    StopRequest,
)
from cellctl.workers import camera as camera_worker
from cellctl.workers import robot as robot_worker
from tests.conftest import free_port


def _cfg(port: int, *extra: str) -> CellConfig:
    ep = f'["tcp/127.0.0.1:{port}"]'
    return load_config(
        None,
        [
            f"bus.listen={ep}",
            f"bus.connect={ep}",
            "robot.speed_scale=200",
            "robot.settle_s=0",
            "robot.joint_state_hz=50",
            "camera.width=320",
            "camera.height=180",
            *extra,
        ],
    )


def _wait_alive(session, cfg: CellConfig, roles: set[str], timeout: float = 20.0) -> None:
    seen: set[str] = set()
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout and not roles <= seen:
        for r in session.liveliness().get(keys.alive_all(cfg.cell_id), timeout=1.0):
            if r.ok is not None:
                role = keys.role_from_alive_key(cfg.cell_id, str(r.ok.key_expr))
                if role:
                    seen.add(role)
        time.sleep(0.05)
    assert roles <= seen, f"workers not alive: {roles - seen}"


@pytest.fixture(scope="module")
def cell() -> Iterator[tuple[CellConfig, object]]:
    """A router, the sim robot worker, the sim camera worker and a client session."""
    cfg = _cfg(free_port(), "sim.dirty=true")
    router = open_session(cfg, "router")
    stop = threading.Event()
    threads = [
        threading.Thread(target=robot_worker.run_worker, args=(cfg, "sim", stop), daemon=True),
        threading.Thread(target=camera_worker.run_worker, args=(cfg, "sim", stop), daemon=True),
    ]
    for t in threads:
        t.start()
    client = open_session(cfg, "client")
    _wait_alive(client, cfg, {"robot", "camera"})
    yield cfg, client
    stop.set()
    for t in threads:
        t.join(10)
    client.close()
    router.close()


def _call(client, cfg: CellConfig, op: str, msg, expect, timeout: float = 60.0):
    return request(client, keys.robot_op(cfg.cell_id, op), msg, expect, timeout=timeout, role="robot")[0]


def test_approach_capture_and_refusals_over_zenoh(cell) -> None:
    cfg, client = cell
    rep = _call(client, cfg, "approach", ApproachRequest(park=True), ApproachReply)
    assert len(rep.joints) == 6
    cap, image = request(
        client, keys.camera_capture(cfg.cell_id), CaptureRequest(), CaptureReply, timeout=30, role="camera"
    )
    img = cv2.imdecode(np.frombuffer(image, np.uint8), cv2.IMREAD_COLOR)
    assert img.shape == (180, 320, 3)
    assert cap.intrinsics.width == 320 and cap.intrinsics.fx == pytest.approx(230.0)
    dt, dr = pose_error(cap.camera_pose.matrix(), rep.camera_pose.matrix())
    assert dt < 1e-9 and dr < 1e-9  # the camera rendered from where the arm is
    # unreachable: refused with the reason, and the worker keeps serving
    far = PoseMsg(position=(3.0, 0.0, 0.0))
    with pytest.raises(WorkerFailed, match="unreachable: wrist centre"):
        _call(client, cfg, "move", MoveRequest(camera_pose=far), MoveReply)
    with pytest.raises(WorkerFailed, match="expected a cellctl/MoveRequest message"):
        request(client, keys.robot_op(cfg.cell_id, "move"), StopRequest(), MoveReply, timeout=10, role="robot")
    st = _call(client, cfg, "state", RobotStateRequest(), RobotState)
    assert np.allclose(st.joints, rep.joints)
    # a reachable move after the refusals
    target = np.asarray(rep.joints) + [0.05, 0.0, 0.0, 0.0, 0.0, 0.05]
    moved = _call(client, cfg, "move", MoveRequest(joints=target.tolist()), MoveReply)
    assert np.allclose(moved.joints, target) and moved.path_length_rad == pytest.approx(np.hypot(0.05, 0.05))
    assert _call(client, cfg, "stop", StopRequest(reason="test"), StopRequest).reason == "test"


def test_joint_states_and_sim_state_are_published(cell) -> None:
    cfg, client = cell
    got: list[JointState] = []
    sims: list[SimState] = []
    sub = client.declare_subscriber(
        keys.robot_joints(cfg.cell_id), lambda s: got.append(decode_as(JointState, s.payload.to_bytes()))
    )
    sub2 = client.declare_subscriber(
        keys.sim_state(cfg.cell_id), lambda s: sims.append(decode_as(SimState, s.payload.to_bytes()))
    )
    time.sleep(1.5)
    sub.undeclare()
    sub2.undeclare()
    assert len(got) >= 10 and got[-1].names[0] == "shoulder_pan"
    assert sims and sims[-1].bin_type == "case_study" and sims[-1].dirty


def test_scenario_change_swaps_the_bin(cell) -> None:
    cfg, client = cell
    st = _call(client, cfg, "scenario", SimScenarioRequest(bin_type="tote", dirty=False, repark=True), SimState)
    assert st.bin_type == "tote" and not st.dirty and st.parked
    with pytest.raises(WorkerFailed, match=r"bin type 'crate' is unknown"):
        _call(client, cfg, "scenario", SimScenarioRequest(bin_type="crate"), SimState)
    rep = _call(client, cfg, "approach", ApproachRequest(park=False, observation_index=0), ApproachReply)
    cap, image = request(
        client,
        keys.camera_capture(cfg.cell_id),
        CaptureRequest(format="jpeg"),
        CaptureReply,
        timeout=30,
        role="camera",
    )
    assert cap.format == "jpeg" and image[:2] == b"\xff\xd8"
    assert rep.observation_index == 0
    _call(client, cfg, "scenario", SimScenarioRequest(bin_type="case_study", dirty=True, repark=True), SimState)


def test_folder_and_opencv_backends(tmp_path: Path) -> None:
    """folder replays images in order; opencv without a device refuses captures but keeps serving."""
    port = free_port()
    folder = tmp_path / "imgs"
    folder.mkdir()
    for i, v in enumerate((40, 200)):
        cv2.imwrite(str(folder / f"{i}.png"), np.full((180, 320, 3), v, np.uint8))
    cfg = _cfg(port, f"camera.folder={folder}")
    router = open_session(cfg, "router")
    stop = threading.Event()
    t = threading.Thread(target=camera_worker.run_worker, args=(cfg, "folder", stop), daemon=True)
    t.start()
    client = open_session(cfg, "client")
    try:
        _wait_alive(client, cfg, {"camera"})
        means = []
        for _ in range(3):
            _, data = request(
                client,
                keys.camera_capture(cfg.cell_id),
                CaptureRequest(),
                CaptureReply,
                timeout=10,
                role="camera",
            )
            means.append(int(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE).mean()))
        assert means == [40, 200, 40]
        stop.set()
        t.join(10)
        stop2 = threading.Event()
        cfg2 = _cfg(port, "camera.device=/nonexistent/video99")
        t2 = threading.Thread(target=camera_worker.run_worker, args=(cfg2, "opencv", stop2), daemon=True)
        t2.start()
        time.sleep(1.0)
        for _ in range(2):
            with pytest.raises(
                WorkerFailed, match=r"camera 'opencv' is not connected: .*'/nonexistent/video99' cannot"
            ):
                request(
                    client,
                    keys.camera_capture(cfg.cell_id),
                    CaptureRequest(),
                    CaptureReply,
                    timeout=10,
                    role="camera",
                )
        stop2.set()
        t2.join(10)
    finally:
        stop.set()
        client.close()
        router.close()
