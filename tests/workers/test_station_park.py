"""The sim arm parks its base at a whole-bin station (ApproachRequest.base_pose, bin frame)."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.errors import RobotError
from cellctl.geometry.transforms import pose_error, transform_from_xyz_rpy
from cellctl.messages import ApproachRequest, PoseMsg
from cellctl.sim import scene


@pytest.fixture
def robot(cfg):
    from cellctl.workers.robot._sim import SimRobot

    cfg.robot.speed_scale = 50.0  # the drive is modelled time
    r = SimRobot(cfg)
    yield r
    r.close()


def test_park_at_a_station_pose_with_the_base_error_and_the_arm_tucked(robot) -> None:
    bt = robot.catalog.get("case_study")
    mesh = robot.catalog.load_mesh("case_study")
    T_bin_station = transform_from_xyz_rpy((0, 0, 0), (0, 0, np.pi / 2)) @ scene.nominal_T_bin_base(bt, mesh)
    reply = robot.approach(
        ApproachRequest(park=True, base_pose=PoseMsg.from_matrix(T_bin_station, "bin"), observe=False)
    )
    assert np.allclose(reply.joints, scene.HOME_JOINTS)
    T_world_base = robot.sim_state().world_T_base.matrix()
    dt, dr = pose_error(robot.scenario.T_world_bin(bt) @ T_bin_station, T_world_base)
    assert 0 < dt <= robot.cfg.sim.approach_error_m + 1e-9  # parked there, with the seeded error
    assert np.degrees(dr) <= robot.cfg.sim.approach_error_deg + 1e-9
    nominal = robot.scenario.T_world_bin(bt) @ scene.nominal_T_bin_base(bt, mesh)
    assert pose_error(nominal, T_world_base)[0] > 0.5  # not the nominal park


def test_a_station_pose_in_another_frame_is_refused(robot) -> None:
    with pytest.raises(RobotError, match="base_pose.frame_id is 'base'; expected 'bin'"):
        robot.approach(ApproachRequest(park=True, base_pose=PoseMsg.from_matrix(np.eye(4), "base")))
