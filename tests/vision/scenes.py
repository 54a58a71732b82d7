"""Shared scene constants of the vision tests: two catalog boards, D435-like intrinsics."""

from __future__ import annotations

import numpy as np

from cellctl.geometry.catalog import BoardSpec
from cellctl.geometry.transforms import transform_from_xyz_rpy
from cellctl.messages import Intrinsics

INTR = Intrinsics(width=1280, height=720, fx=910.0, fy=910.0, cx=640.0, cy=360.0)
"""A D435-like test camera, 1 % shorter focal length than the cell's model (920 px): the
identification scenes and their thresholds were tuned with it, and identify() must not
depend on the camera being exactly the cell's."""

# Board placement on the bin: upright on a side wall, 0.2 m below the rim (any rigid transform works).
T_BIN_BOARD = transform_from_xyz_rpy((-0.21, -0.40, -0.15), (np.pi / 2, 0.0, 0.0))

SPEC_A = BoardSpec(squares_x=7, squares_y=5, square_m=0.06, marker_m=0.045, first_id=0, T_bin_board=T_BIN_BOARD)
SPEC_B = BoardSpec(squares_x=7, squares_y=5, square_m=0.06, marker_m=0.045, first_id=17, T_bin_board=T_BIN_BOARD)
SPEC_FOREIGN = BoardSpec(squares_x=7, squares_y=5, square_m=0.06, marker_m=0.045, first_id=500, T_bin_board=np.eye(4))
