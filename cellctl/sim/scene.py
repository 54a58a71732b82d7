"""The simulated cell: scenario (which bin, where, dirty or not), parking model, observation poses.

World frame: cabin floor, z = 0, origin at the cabin centre; cabin walls at
``|x| = CABIN_HALF[0]``, ``|y| = CABIN_HALF[1]``. A bin stands on the floor: its pose is
given as the footprint position ``(x, y)``, a lift ``z`` (0 = on the floor) and a yaw, so
``T_world_bin = transl(x, y, z + height) · Rz(yaw)`` (the bin frame is at the top opening).

Parking: the mobile base parks on the bin's **board side** (bin −y), its arm's base +x axis
facing the bin, with a seeded random error (uniform in a disc of ``approach_error_m`` and
±``approach_error_deg`` of yaw). The robot only knows the nominal relation
:func:`nominal_T_bin_base`; the true one is in the scenario (ground truth).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import RobotError
from cellctl.geometry import robot_model as rm
from cellctl.geometry.catalog import BinMesh, BinType
from cellctl.geometry.transforms import invert, rotation_about, transform_from, transform_from_xyz_rpy

__all__ = [
    "CABIN_HALF",
    "HOME_JOINTS",
    "Scenario",
    "nominal_T_bin_base",
    "localised",
    "observation_T_bin_cam",
    "park",
]

CABIN_HALF = (2.5, 2.5)
"""Cabin half-extents (m) in x and y; walls 3 m high."""
CABIN_HEIGHT = 3.0

HOME_JOINTS = np.array([np.pi, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0])
"""Arm straight up ("candle"): clear of the bin whatever the parking error."""

PARK_DISTANCE_M = 0.75
"""Horizontal distance from the bin's board-side extent to the robot base origin: leaves room
for the camera between the robot and the board (the mobile base front is 0.58 m from the bin)."""

OBSERVATION_DISTANCE_M = 0.40
_OBS_OFFSETS_DEG = ((0, 20), (15, 20), (-15, 20), (0, 32), (15, 32), (-15, 32), (0, 8), (25, 20), (-25, 20))
"""(yaw, pitch) of each observation pose's line of sight; positive pitch looks down at the board."""


@dataclass(frozen=True)
class Scenario:
    """What the sim world looks like now (the robot worker owns it and publishes it).

    Attributes:
        bin_type: catalog name.
        bin_xyz_yaw: footprint x, y (m), lift z (m), yaw (rad) in the world frame.
        dirty: whether powder is on the bin.
        powder_amount: 0..1, fraction of the maximum contamination.
        seed: seeds parking error and powder placement.
        park_offset_xy_yaw: a systematic parking offset (x, y in m, yaw in rad, in the parked
            base's frame) on top of the random error: the base cannot reach its nominal spot
            (an obstacle in the cabin), so the bin stands somewhere new relative to the robot.
        T_world_base: the parked robot base pose (None before the first approach).
    """

    bin_type: str
    bin_xyz_yaw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    dirty: bool = False
    powder_amount: float = 0.5
    seed: int = 0
    park_offset_xy_yaw: tuple[float, float, float] = (0.0, 0.0, 0.0)
    T_world_base: tuple[tuple[float, ...], ...] | None = None

    def T_world_bin(self, bin_type: BinType) -> NDArray[np.float64]:
        x, y, z, yaw = self.bin_xyz_yaw
        return transform_from(rotation_about((0, 0, 1), yaw), [x, y, z + bin_type.height_m])

    def base(self) -> NDArray[np.float64]:
        """``T_world_base``; before parking the base waits at the cabin's -y side."""
        if self.T_world_base is None:
            return transform_from_xyz_rpy([0.0, -CABIN_HALF[1] + 0.6, rm.BASE_HEIGHT_M], [0, 0, np.pi / 2])
        return np.asarray(self.T_world_base, dtype=np.float64)

    def with_base(self, T_world_base: NDArray[np.float64]) -> Scenario:
        return replace(self, T_world_base=tuple(map(tuple, np.asarray(T_world_base).tolist())))


def nominal_T_bin_base(bin_type: BinType, mesh: BinMesh) -> NDArray[np.float64]:
    """Where the base parks in the bin frame when there is no error: in front of the board side."""
    board_T = bin_type.T_bin_board()
    w, h = bin_type.board.size_m
    board_pts = board_T[:3, :3] @ np.array([[0, 0, 0], [w, 0, 0], [0, h, 0], [w, h, 0]]).T + board_T[:3, 3:4]
    y_min = min(float(mesh.vertices[:, 1].min()), float(board_pts[1].min()))
    y = y_min - PARK_DISTANCE_M
    z = -bin_type.height_m + rm.BASE_HEIGHT_M  # bin frame is at the top opening; floor at -height
    return transform_from_xyz_rpy([0.0, y, z], [0.0, 0.0, np.pi / 2])


def park(
    scenario: Scenario,
    bin_type: BinType,
    mesh: BinMesh,
    error_m: float,
    error_deg: float,
    attempt: int = 0,
    T_bin_base: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """True ``T_world_base`` after parking at ``T_bin_base`` (default: the nominal pose) plus a seeded planar error."""
    err = _planar_error(np.random.default_rng([scenario.seed, attempt, 7919]), error_m, error_deg)
    ox, oy, oyaw = scenario.park_offset_xy_yaw
    offset = transform_from_xyz_rpy([ox, oy, 0.0], [0.0, 0.0, oyaw])
    target = nominal_T_bin_base(bin_type, mesh) if T_bin_base is None else np.asarray(T_bin_base, dtype=float)
    return scenario.T_world_bin(bin_type) @ target @ offset @ err


def localised(scenario: Scenario, error_m: float, error_deg: float, attempt: int = 0) -> NDArray[np.float64]:
    """The parked ``T_world_base`` as the twin's base reports it (its localisation; the world is its map).

    The truth times a planar error drawn once per park (seeded by the scenario's seed and the park
    attempt, apart from the parking error's draw): uniform in a disc of ``error_m`` and ±``error_deg``
    of yaw, as :func:`park` draws the parking error.
    """
    return scenario.base() @ _planar_error(np.random.default_rng([scenario.seed, attempt, 104729]), error_m, error_deg)


def _planar_error(rng: np.random.Generator, error_m: float, error_deg: float) -> NDArray[np.float64]:
    """A base-frame planar error: uniform in a disc of ``error_m``, yaw uniform in ±``error_deg``."""
    r = error_m * np.sqrt(rng.uniform())
    a = rng.uniform(0, 2 * np.pi)
    dyaw = np.radians(error_deg) * rng.uniform(-1, 1)
    return transform_from_xyz_rpy([r * np.cos(a), r * np.sin(a), 0.0], [0.0, 0.0, dyaw])


def observation_T_bin_cam(bin_type: BinType, index: int) -> NDArray[np.float64]:
    """Camera pose (bin frame) of observation pose ``index``: looking at the board's centre.

    Index 0 looks straight at the board from :data:`OBSERVATION_DISTANCE_M`; higher indices
    look from the side/above/below (retries after a failed identification).

    Raises:
        RobotError: ``index`` is beyond the available observation poses.
    """
    if not 0 <= index < len(_OBS_OFFSETS_DEG):
        raise RobotError(f"observation_index {index} is out of range; expected 0..{len(_OBS_OFFSETS_DEG) - 1}")
    w, h = bin_type.board.size_m
    T_bin_centre = bin_type.T_bin_board() @ transform_from(np.eye(3), [w / 2, h / 2, 0.0])
    yaw, pitch = np.radians(_OBS_OFFSETS_DEG[index])
    # rotate the line of sight about the board's y (left/right) and x (up/down) axes
    R = rotation_about((0, 1, 0), yaw) @ rotation_about((1, 0, 0), -pitch)
    T_centre_cam = transform_from(R, R @ np.array([0.0, 0.0, -OBSERVATION_DISTANCE_M]))
    return T_bin_centre @ T_centre_cam


def n_observation_poses() -> int:
    return len(_OBS_OFFSETS_DEG)


def base_in_reach(T_base_cam: NDArray[np.float64]) -> bool:
    """Cheap pre-check: is the camera within the arm's nominal reach of the shoulder?"""
    return float(np.linalg.norm(T_base_cam[:3, 3] - [0, 0, rm.DH_D[0]])) < rm.REACH_M + 0.2


def T_base_bin_of(scenario: Scenario, bin_type: BinType) -> NDArray[np.float64]:
    """True bin pose in the robot base frame (ground truth in the sim)."""
    return invert(scenario.base()) @ scenario.T_world_bin(bin_type)
