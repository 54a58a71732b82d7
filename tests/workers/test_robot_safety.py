"""The sim arm never keeps moving for a supervisor that cannot stop it (issue 8, item 1).

* the supervisor's liveliness token goes (crash, lost link) → the motion in progress stops;
* the robot worker is frozen mid-motion (SIGSTOP) → on SIGCONT it stops where it was
  instead of jumping to where the path says it should be by now.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from cellctl.bus import keys
from cellctl.bus.rpc import request
from cellctl.bus.session import open_session
from cellctl.config import CellConfig, load_config
from cellctl.errors import CellError
from cellctl.messages import MoveReply, MoveRequest, RobotState, RobotStateRequest
from cellctl.sim import scene
from cellctl.workers import robot as robot_worker
from tests.conftest import free_port

# A base-joint swing with the arm tucked: long (2 rad) and free of collisions.
TARGET = (scene.HOME_JOINTS + np.array([2.0, 0, 0, 0, 0, 0])).tolist()


# slow motions (a 2 rad swing lasts seconds); a long lease, so a loaded machine cannot turn the
# short freeze into a lost link
SLOW = ["robot.speed_scale=0.5", "robot.settle_s=0", "bus.lease_ms=5000"]


def _cfg(port: int) -> CellConfig:
    ep = f'["tcp/127.0.0.1:{port}"]'
    return load_config(None, [f"bus.listen={ep}", f"bus.connect={ep}", *SLOW])


def _joints(session, cfg: CellConfig) -> np.ndarray:
    st, _ = request(session, keys.robot_op(cfg.cell_id, "state"), RobotStateRequest(), RobotState, timeout=5)
    return np.array(st.joints)


def _move_in_background(session, cfg: CellConfig) -> tuple[threading.Thread, dict]:
    out: dict = {}

    def go() -> None:
        try:
            out["reply"] = request(
                session, keys.robot_op(cfg.cell_id, "move"), MoveRequest(joints=TARGET), MoveReply, timeout=60
            )
        except CellError as err:  # WorkerFailed expected; anything else shows in the assertion
            out["error"] = f"{type(err).__name__}: {err}"

    t = threading.Thread(target=go, daemon=True)
    t.start()
    return t, out


def _wait_moving(session, cfg: CellConfig, q0: np.ndarray) -> None:
    deadline = time.monotonic() + 20
    while np.abs(_joints(session, cfg) - q0).max() < 0.02:
        assert time.monotonic() < deadline, "the arm did not start moving"
        time.sleep(0.05)


def _wait_token(session, key: str) -> None:
    deadline = time.monotonic() + 20
    while not [r for r in session.liveliness().get(key, timeout=1.0) if r.ok is not None]:
        assert time.monotonic() < deadline, f"{key} did not appear"
        time.sleep(0.05)


def test_motion_stops_when_the_supervisor_token_goes() -> None:
    cfg = _cfg(free_port())
    router = open_session(cfg, "router")
    stop = threading.Event()
    worker = threading.Thread(target=robot_worker.run_worker, args=(cfg, "sim", stop), daemon=True)
    worker.start()
    supervisor = open_session(cfg, "client")
    try:
        token = supervisor.liveliness().declare_token(keys.alive(cfg.cell_id, "supervisor"))  # noqa: F841 - kept alive
        _wait_token(router, keys.alive(cfg.cell_id, "robot"))
        q0 = _joints(router, cfg)
        t, out = _move_in_background(router, cfg)
        _wait_moving(router, cfg, q0)
        supervisor.close()  # the supervisor dies: its token goes
        t.join(10)
        assert "supervisor lost" in out.get("error", ""), out
        q_stop = _joints(router, cfg)
        time.sleep(0.5)
        assert np.abs(_joints(router, cfg) - q_stop).max() < 1e-9, "the arm moved after the stop"
        assert np.abs(q_stop - np.array(TARGET)).max() > 0.1, "the motion was not interrupted"
    finally:
        stop.set()
        worker.join(10)
        router.close()


@pytest.mark.parametrize("freeze_s", [1.6])
def test_a_frozen_robot_worker_stops_instead_of_catching_up(freeze_s: float) -> None:
    cfg = _cfg(free_port())
    ep = cfg.bus.listen[0]
    router = open_session(cfg, "router")
    overrides = [f'bus.listen=["{ep}"]', f'bus.connect=["{ep}"]', *SLOW]
    cmd = [sys.executable, "-m", "cellctl", "worker", "robot"]
    for ov in overrides:
        cmd += ["--set", ov]
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL)
    try:
        _wait_token(router, keys.alive(cfg.cell_id, "robot"))
        q0 = _joints(router, cfg)
        t, out = _move_in_background(router, cfg)
        _wait_moving(router, cfg, q0)
        proc.send_signal(signal.SIGSTOP)
        time.sleep(freeze_s)  # shorter than the lease: the link survives, only the worker's clock jumps
        proc.send_signal(signal.SIGCONT)
        t.join(20)
        assert "frozen" in out.get("error", ""), out
        q_after = _joints(router, cfg)
        assert np.abs(q_after - np.array(TARGET)).max() > 0.1, "the arm jumped ahead to where the path would be"
        time.sleep(0.5)
        assert np.abs(_joints(router, cfg) - q_after).max() < 1e-9, "the arm moved after the stop"
    finally:
        proc.send_signal(signal.SIGCONT)
        proc.terminate()
        proc.wait(20)
        router.close()


def test_a_stall_before_the_motion_starts_refuses_the_motion() -> None:
    """Frozen while planning (the tick went stale): the motion must not start at all."""
    from cellctl.errors import RobotError
    from cellctl.workers.robot._sim import FROZEN_GAP_S, SimRobot

    robot = SimRobot(_cfg(free_port()))
    try:
        q0 = robot.joints
        robot._tick -= FROZEN_GAP_S + 1  # as the stall watch would find it on resumption, before it ran
        with pytest.raises(RobotError, match="frozen"):
            robot.move(MoveRequest(joints=TARGET))
        assert np.abs(robot.joints - q0).max() == 0.0
    finally:
        robot.close()


def test_the_stall_watch_stops_a_request_in_progress() -> None:
    from cellctl.workers.robot._sim import FROZEN_GAP_S, SimRobot

    robot = SimRobot(_cfg(free_port()))
    try:
        with robot._busy:  # a request in progress
            robot._tick -= FROZEN_GAP_S + 1
            deadline = time.monotonic() + 2
            while not robot._stop.is_set() and time.monotonic() < deadline:
                time.sleep(0.01)
            assert robot._stop.is_set() and "frozen" in robot._stop_reason
    finally:
        robot.close()
