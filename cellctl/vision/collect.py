"""Hand–eye data collection over the bus: move the arm around the board, capture, solve.

Talks to the robot and camera workers (sim or real) with the wire contract only:
``robot/state`` (RobotStateRequest → RobotState), ``robot/move`` (MoveRequest → MoveReply),
``camera/capture`` (CaptureRequest → CaptureReply + image). The board must be visible from
the arm's current pose; the views are generated around it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.bus import keys
from cellctl.bus.rpc import request
from cellctl.errors import CameraError, CellError, IdentificationError, WorkerFailed
from cellctl.geometry.transforms import look_at
from cellctl.images import decode_image
from cellctl.messages import (
    CaptureReply,
    CaptureRequest,
    Intrinsics,
    MoveReply,
    MoveRequest,
    PoseMsg,
    RobotState,
    RobotStateRequest,
)
from cellctl.vision.handeye import HandEyeResult, solve_hand_eye
from cellctl.vision.identify import Identification, identify

__all__ = ["HandEyeView", "collect_hand_eye", "observation_poses"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class HandEyeView:
    """One calibration view: where the flange was and where the camera saw the board."""

    index: int
    T_base_flange: NDArray[np.float64]
    T_cam_board: NDArray[np.float64]
    reproj_rms_px: float
    n_corners: int


def observation_poses(
    T_base_board: NDArray[np.float64],
    centre_board: NDArray[np.float64],
    n: int,
    distance_m: float,
    rng: np.random.Generator,
    cone_deg: float = 25.0,
    roll_deg: float = 30.0,
) -> list[NDArray[np.float64]]:
    """Camera poses on a spherical cap in front of the board, all looking at its centre.

    Directions spread over the cap (golden-angle spiral) with random roll, so relative
    rotations have well-spread axes (what Park–Martin needs).
    """
    c = T_base_board[:3, :3] @ centre_board + T_base_board[:3, 3]
    normal = -T_base_board[:3, 2]  # board +z points into the board; the camera side is −z
    a = np.cross(normal, (0.0, 0.0, 1.0))
    if np.linalg.norm(a) < 1e-6:
        a = np.cross(normal, (1.0, 0.0, 0.0))
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    out = []
    for k in range(n):
        tilt = np.radians(cone_deg) * np.sqrt((k + 0.5) / n)
        az = k * np.pi * (3.0 - np.sqrt(5.0))
        d = np.cos(tilt) * normal + np.sin(tilt) * (np.cos(az) * a + np.sin(az) * b)
        out.append(look_at(c + distance_m * d, c, roll_rad=float(np.radians(rng.uniform(-roll_deg, roll_deg)))))
    return out


def _capture(session: Any, cfg: Any) -> tuple[NDArray[np.uint8], Intrinsics]:
    meta, raw = request(
        session,
        keys.camera_capture(cfg.cell_id),
        CaptureRequest(format="png"),
        CaptureReply,
        timeout=cfg.supervisor.timeouts.capture,
        role="camera",
    )
    if raw is None:
        raise CellError("camera capture reply carried no image payload")
    budget = cfg.camera.max_image_pixels
    img = decode_image(raw, f"from the camera ({meta.format})", order="bgr", error=CameraError, max_pixels=budget)
    return img, meta.intrinsics


def _state(session: Any, cfg: Any) -> RobotState:
    st, _ = request(
        session,
        keys.robot_op(cfg.cell_id, "state"),
        RobotStateRequest(),
        RobotState,
        timeout=cfg.supervisor.timeouts.default,
        role="robot",
    )
    return st


def collect_hand_eye(
    session: Any,
    cfg: Any,
    catalog: Any,
    n_views: int = 12,
    distance_m: float | None = None,
    seed: int = 0,
    progress: bool = True,
) -> tuple[HandEyeResult, list[HandEyeView], list[str]]:
    """Move the arm through ``n_views`` poses around the board in view, then solve ``T_flange_cam``.

    Args:
        session: an open Zenoh client session.
        cfg: the cell config (cell id, timeouts).
        catalog: the bin catalog (which boards to look for).
        n_views: poses to try (unreachable ones and views without the board are skipped).
        distance_m: camera–board distance of the views; ``None`` keeps the current one.
        seed: RNG seed of the view rolls.
        progress: tqdm bar on stderr.

    Returns:
        ``(result, views, skipped)``: the solution, the views used, ``"pose k: reason"`` lines.

    Raises:
        IdentificationError: the board is not visible from the current pose.
        CellError: fewer than 3 usable views, or a degenerate set (from :func:`solve_hand_eye`).
        WorkerUnavailable, WorkerTimeout: the robot or camera worker is missing or hung.
    """
    from tqdm import tqdm

    st0 = _state(session, cfg)
    img0, intr = _capture(session, cfg)
    first: Identification = identify(img0, intr, st0.camera_pose.matrix(), catalog)
    T_base_board = first.T_base_cam @ first.T_cam_board
    w, h = first.board_size_m
    centre = np.array([w / 2.0, h / 2.0, 0.0])
    dist = float(distance_m) if distance_m is not None else first.distance_m
    poses = observation_poses(T_base_board, centre, n_views, dist, np.random.default_rng(seed))
    views: list[HandEyeView] = []
    skipped: list[str] = []
    for k, T_base_cam in enumerate(tqdm(poses, desc="hand-eye views", unit="pose", disable=not progress)):
        try:
            request(
                session,
                keys.robot_op(cfg.cell_id, "move"),
                MoveRequest(camera_pose=PoseMsg.from_matrix(T_base_cam)),
                MoveReply,
                timeout=cfg.supervisor.timeouts.move,
                role="robot",
            )
        except WorkerFailed as err:  # unreachable / collision: try the next pose
            skipped.append(f"pose {k}: {err}")
            continue
        st = _state(session, cfg)
        img, intr = _capture(session, cfg)
        try:
            ident = identify(img, intr, None, catalog)
        except IdentificationError as err:
            skipped.append(f"pose {k}: {err}")
            continue
        views.append(HandEyeView(k, st.flange_pose.matrix(), ident.T_cam_board, ident.reproj_rms_px, ident.n_corners))
        log.info("hand-eye view %d: %d corners, %.3f px", k, ident.n_corners, ident.reproj_rms_px)
    try:  # back to where the operator left the arm
        request(
            session,
            keys.robot_op(cfg.cell_id, "move"),
            MoveRequest(joints=list(st0.joints)),
            MoveReply,
            timeout=cfg.supervisor.timeouts.move,
            role="robot",
        )
    except WorkerFailed as err:
        log.warning("could not return to the start pose: %s", err)
    if len(views) < 3:
        raise CellError(f"hand-eye: only {len(views)} usable views of {n_views} (need ≥ 3); skipped: {skipped}")
    result = solve_hand_eye([v.T_base_flange for v in views], [v.T_cam_board for v in views])
    return result, views, skipped
