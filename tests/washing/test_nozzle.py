"""The nozzle model: derived quantities, the frustum the planner uses, and bad configs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cellctl.app import preflight
from cellctl.config import load_config
from cellctl.errors import ConfigError
from cellctl.planning.robot import default_robot_model
from cellctl.washing.nozzle import NozzleModel


def test_default_config_has_a_nozzle_and_two_passes() -> None:
    """The default cell config carries a nozzle; 80 % per pass to ≤ 5 % left needs 2 passes."""
    n = NozzleModel.from_config(load_config().nozzle)
    assert n.required_passes == 2
    assert NozzleModel(removal_per_pass=0.5, clean_residual=0.05).required_passes == 5
    assert n.distances[0] >= n.working_distance_m[0] and n.distances[-1] <= n.working_distance_m[1]


@pytest.mark.parametrize(
    ("override", "named"),
    [
        ("nozzle.working_distance_m=[0.3,1.25]", "beyond the arm's reach"),
        ("nozzle.working_distance_m=[0.01,0.2]", "lance"),
        ("nozzle.working_distance_m=[0.2,0.1]", "near < far"),
        ("nozzle.footprint_m=0.3", "wider than its cone"),
        ("nozzle.half_angle_deg=70", "half_angle_deg"),
        ("nozzle.spray=1", "unknown key 'nozzle.spray'"),
    ],
)
def test_bad_nozzle_config_is_a_config_error_naming_the_value(override: str, named: str) -> None:
    with pytest.raises(ConfigError, match=named):  # as `validate` and `run` check it (cellctl.config imports no model)
        preflight(load_config(None, [override]))


def test_sprayed_is_the_cone_cut_to_footprint_and_incidence() -> None:
    """Points on a plane 0.15 m ahead: inside the footprint radius sprayed, outside not; a face
    turned beyond the incidence limit not; a point nearer than the working distance not."""
    n = NozzleModel()
    T = np.eye(4)
    r = n.footprint_m / 2
    pts = np.array([[0, 0, 0.15], [0.9 * r, 0, 0.15], [1.1 * r, 0, 0.15], [0, 0, 0.05], [0, 0, 0.15]])
    nrm = np.array([[0, 0, -1.0]] * 4 + [[math.sin(math.radians(70)), 0, -math.cos(math.radians(70))]])
    assert n.sprayed(T, pts, nrm).tolist() == [True, True, False, False, False]


def test_frustum_camera_circumscribes_the_cone_and_robot_tool_is_the_nozzle() -> None:
    n = NozzleModel()
    cam = n.frustum_camera()
    assert cam.fov_deg[0] == pytest.approx(2 * n.half_angle_deg)
    assert cam.dov == n.working_distance_m
    robot = n.robot_with_nozzle(default_robot_model())
    q = np.array([[0.3, -1.2, 1.1, -1.4, -1.5, 0.2]])
    T_base_flange = default_robot_model().fk_frames(q)[0, 6]
    assert np.allclose(robot.fk_cam(q)[0], T_base_flange @ n.T_flange_nozzle())
    assert np.allclose(robot.fk_cam(q)[0, :3, 3], T_base_flange[:3, 3] + n.mount_xyz_rpy[2] * T_base_flange[:3, 2])
