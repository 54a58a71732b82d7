"""Planner fixtures: a small watertight open box bin and a base pose beside it."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.planning.pipeline import base_pose_from_xyz_yaw
from cellctl.planning.robot import default_robot_model
from cellctl.planning.shapes import open_box_bin

BOX_SIZE = (0.8, 0.6, 0.8)
BOX_BASE = (0.0, -0.95, -0.1, 90.0)  # base plate 0.7 m above the floor (the box stands on it)


@pytest.fixture(scope="session")
def box():
    return open_box_bin(BOX_SIZE, max_edge=0.1)


@pytest.fixture(scope="session")
def robot():
    return default_robot_model()


@pytest.fixture(scope="session")
def T_bin_base() -> np.ndarray:
    return base_pose_from_xyz_yaw(*BOX_BASE)
