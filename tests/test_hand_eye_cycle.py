"""`cellctl calibrate hand-eye` end to end into a cycle (issue 16 item 4, slow).

The CLI calibrates against the twin's real sim robot and camera worker processes and writes the file;
the next cycle's robot worker runs with ``robot.hand_eye`` pointing at that file, and every camera
pose it reports in the cycle is the flange pose times *that* transform, not the nominal mount."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cellctl.app import build_cell
from cellctl.bus import keys
from cellctl.bus.plc_client import PlcClient
from cellctl.bus.rpc import request
from cellctl.bus.session import open_session
from cellctl.config import load_config
from cellctl.geometry import robot_model as rm
from cellctl.geometry.catalog import load_catalog
from cellctl.geometry.transforms import pose_error
from cellctl.messages import (
    ApproachReply,
    ApproachRequest,
    PlanLookupReply,
    PlanLookupRequest,
    PlannedViewpoint,
    PoseMsg,
    RobotState,
    RobotStateRequest,
)
from cellctl.sim import scene
from tests.conftest import cfg_overrides, free_port
from tests.fakes.workers import FakeCell, fake_identify


def _workers(overrides: list[str]) -> list[subprocess.Popen[bytes]]:
    args = [a for o in overrides for a in ("--set", o)]
    return [subprocess.Popen([sys.executable, "-m", "cellctl", "worker", r, *args]) for r in ("robot", "camera")]


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in procs:
        p.terminate()
    for p in procs:
        p.wait(20)


def _robot_state(session, cfg) -> RobotState:
    deadline = time.monotonic() + 90
    while True:
        try:
            st, _ = request(session, keys.robot_op(cfg.cell_id, "state"), RobotStateRequest(), RobotState,
                            timeout=10, role="robot")  # fmt: skip
            return st
        except Exception:
            if time.monotonic() > deadline:
                raise
            time.sleep(1.0)


Q_VPS = [scene.HOME_JOINTS + np.array([0.0, 0.0, 0.0, 0.15 * (i % 2), 0.0, 0.6 * (1 if i % 2 else -1)]) for i in (0, 1)]
"""The plan's viewpoints: wrist motions near home (reachable and clear of the bin)."""


class _Plan(FakeCell):
    """Classifier and planner doubles; the plan's camera poses are the calibrated camera's at Q_VPS."""

    T_he: np.ndarray | None = None

    def _lookup(self, req: PlanLookupRequest, _: bytes | None) -> PlanLookupReply:
        self._guard("lookup")
        assert self.T_he is not None
        vps = [
            PlannedViewpoint(
                index=i, camera_pose=PoseMsg.from_matrix(rm.fk(q) @ self.T_he), joints=q.tolist(), faces=[i]
            )
            for i, q in enumerate(Q_VPS)
        ]
        return PlanLookupReply(hit=True, plan_id="plan-he", viewpoints=vps, coverage=0.9, mesh_faces=10)


@pytest.mark.slow
def test_the_calibration_the_cli_writes_is_the_next_cycles_camera_mount(tmp_path: Path) -> None:
    from cellctl.cli import main

    port = free_port()
    base = [*cfg_overrides(tmp_path, port), "robot.speed_scale=50"]
    cfg = load_config(None, base)
    out = tmp_path / "models" / "calibration" / "hand_eye.json"
    router = open_session(cfg, "router")  # no daemon yet: the calibration talks to the workers alone
    procs = _workers(base)
    try:
        with open_session(cfg, "client") as s:
            _robot_state(s, cfg)  # the worker serves
            # parked and looking at the bin's board, as an operator starts a calibration
            request(
                s, keys.robot_op(cfg.cell_id, "approach"), ApproachRequest(), ApproachReply, timeout=120, role="robot"
            )
        assert main(["calibrate", "hand-eye", "--views", "8", "--out", str(out), *[
            a for o in base for a in ("--set", o)]]) == 0  # fmt: skip
    finally:
        _stop(procs)
        router.close()
    T_he = np.array(json.loads(out.read_text())["T_flange_cam_matrix"])
    # the twin's camera is the nominal mount: the calibration finds it, to its noise
    dt, dr = pose_error(T_he, rm.T_FLANGE_CAM)
    assert dt < 1e-3 and np.degrees(dr) < 0.1
    assert dt > 1e-7  # and is an estimate, not the nominal constant: what follows can tell them apart

    run = [*base, f"robot.hand_eye={out}"]
    cfg2 = load_config(None, run)
    cell = build_cell(cfg2, identification=(fake_identify, load_catalog(cfg2.path(cfg2.catalog))))
    procs = _workers(run)
    fakes = _Plan(cfg2, roles=("classifier", "planner"))
    fakes.T_he = T_he
    fakes.start()
    plc = PlcClient(cfg2, "test")
    try:
        assert plc.wait_workers(("robot", "camera", "classifier", "planner"), 90)
        assert plc.command("reset", timeout=10).accepted
        deadline = time.monotonic() + 30
        while cell.supervisor.state != "Idle":
            assert time.monotonic() < deadline, cell.supervisor.state
            time.sleep(0.05)
        assert plc.command("start", timeout=10).accepted
        res = plc.results.get(timeout=240)
        assert res.outcome == "completed", res.reason
        assert [v.error for v in res.viewpoints] == [None, None]
        for v, q in zip(res.viewpoints, Q_VPS, strict=True):
            # the camera pose the robot worker reported in the cycle is the file's mount at those joints
            dt, dr = pose_error(v.camera_pose.matrix(), rm.fk(q) @ T_he)
            assert dt < 1e-5 and dr < 1e-5
        st = _robot_state(plc.session, cfg2)
        q = np.array(st.joints)
        assert np.allclose(st.camera_pose.matrix(), rm.fk(q) @ T_he, atol=1e-9)  # the file's mount
        assert not np.allclose(st.camera_pose.matrix(), rm.camera_pose(q), atol=1e-9)  # not the nominal one
    finally:
        plc.close()
        fakes.close()
        _stop(procs)
        cell.close()
