"""`collect_hand_eye` against the twin's real sim robot and camera worker processes (slow)."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

from cellctl.bus import keys
from cellctl.bus.rpc import request
from cellctl.bus.session import open_session
from cellctl.config import load_config
from cellctl.geometry.transforms import pose_error
from cellctl.messages import ApproachReply, ApproachRequest

from ..conftest import free_port


@pytest.mark.slow
def test_hand_eye_recovers_the_twin_camera_mount() -> None:
    from cellctl.geometry import robot_model as rm
    from cellctl.geometry.catalog import load_catalog
    from cellctl.vision.collect import collect_hand_eye

    ep = f'["tcp/127.0.0.1:{free_port()}"]'
    ov = [f"bus.listen={ep}", f"bus.connect={ep}", "robot.speed_scale=50", "robot.settle_s=0"]
    cfg = load_config(None, ov)
    router = open_session(cfg, "router")
    args = [a for o in ov for a in ("--set", o)]
    procs = [subprocess.Popen([sys.executable, "-m", "cellctl", "worker", r, *args]) for r in ("robot", "camera")]
    try:
        with open_session(cfg, "client") as s:
            deadline = time.monotonic() + 60
            while True:  # wait for the robot worker to serve
                try:
                    request(
                        s,
                        keys.robot_op(cfg.cell_id, "approach"),
                        ApproachRequest(),
                        ApproachReply,
                        timeout=120,
                        role="robot",
                    )
                    break
                except Exception:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(1.0)
            cat = load_catalog(cfg.path(cfg.catalog))
            res, views, _ = collect_hand_eye(s, cfg, cat, n_views=8, seed=0, progress=False)
        dt, dr = pose_error(res.T_flange_cam, rm.T_FLANGE_CAM)
        assert len(views) >= 6
        assert dt * 1000 < 1.0 and np.degrees(dr) < 0.1
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.wait(20)
        router.close()
