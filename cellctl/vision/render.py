"""Exact pinhole renders of ChArUco boards, for tests, the pose bench and debugging.

A board is a plane, so its image under a pinhole camera is exactly a homography of the
board texture. The renderer warps the board image (with a half-square white quiet zone) at
``supersample``× resolution and box-filters it down (anti-aliasing), lights it with a smooth
gradient and an exposure factor, blurs it (optics), optionally adds motion blur, and adds
Gaussian sensor noise. Ground truth is the ``T_cam_board`` given.

Pixel convention: OpenCV's — integer pixel coordinates are pixel centres. A supersampled
pixel grid of factor ``f`` maps to the final grid by ``u_s = f * u + (f - 1) / 2``.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.errors import CellError
from cellctl.messages import Intrinsics
from cellctl.vision.board import make_board

__all__ = ["RenderSettings", "board_outline", "project", "random_view", "render_boards", "view_of_board"]


@dataclass(frozen=True)
class RenderSettings:
    """Image-formation settings of a synthetic render.

    Attributes:
        noise_sigma: Gaussian sensor noise, grey levels (0-255).
        blur_sigma: optical blur, final-image pixels (Gaussian sigma).
        exposure: multiplies the scene radiance before clipping at 255; > 1.5 overexposes.
        light_gradient: relative illumination fall-off across the image (0 = uniform).
        motion_blur_px: length of a linear motion-blur kernel in final pixels (0 = none).
        motion_angle_deg: direction of the motion blur in the image, degrees.
        supersample: render at this factor and box-filter down (anti-aliasing).
        black: reflectance of the printed black; white: of the paper.
        background: mean grey level (0-1) of the scene behind the board.
    """

    noise_sigma: float = 2.0
    blur_sigma: float = 0.6
    exposure: float = 1.0
    light_gradient: float = 0.25
    motion_blur_px: float = 0.0
    motion_angle_deg: float = 0.0
    supersample: int = 3
    black: float = 0.06
    white: float = 0.88
    background: float = 0.45


def project(intr: Intrinsics, T_cam_obj: NDArray[np.float64], pts_obj: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pinhole projection (no distortion) of object points (N, 3) → pixels (N, 2)."""
    P = (T_cam_obj[:3, :3] @ np.asarray(pts_obj, dtype=np.float64).T).T + T_cam_obj[:3, 3]
    return np.column_stack([intr.fx * P[:, 0] / P[:, 2] + intr.cx, intr.fy * P[:, 1] / P[:, 2] + intr.cy])


def board_outline(spec: Any, margin_squares: float = 0.0) -> NDArray[np.float64]:
    """Outer corners (4, 3) of the board in the board frame, optionally grown by a margin."""
    m = margin_squares * spec.square_m
    w = spec.squares_x * spec.square_m
    h = spec.squares_y * spec.square_m
    return np.array([[-m, -m, 0], [w + m, -m, 0], [w + m, h + m, 0], [-m, h + m, 0]], dtype=np.float64)


@functools.lru_cache(maxsize=6)
def _texture(key: tuple[int, int, float, float, str, int, bool], px_per_square: int) -> NDArray[np.float32]:
    """Board image with a half-square quiet zone, reflectance-normalised to 0..1 (cached)."""
    sx, sy, sq, mk, dic, first, legacy = key

    class _S:  # a hashable key back into a spec-like object
        squares_x, squares_y, square_m, marker_m, dictionary, first_id, legacy_pattern = (
            sx,
            sy,
            sq,
            mk,
            dic,
            first,
            legacy,
        )

    board = make_board(_S)
    margin = px_per_square // 2
    size = (sx * px_per_square + 2 * margin, sy * px_per_square + 2 * margin)
    return board.generateImage(size, marginSize=margin, borderBits=1).astype(np.float32) / 255.0


def _spec_key(spec: Any) -> tuple[int, int, float, float, str, int, bool]:
    return (
        int(spec.squares_x),
        int(spec.squares_y),
        float(spec.square_m),
        float(spec.marker_m),
        str(spec.dictionary),
        int(spec.first_id),
        bool(getattr(spec, "legacy_pattern", False)),
    )


def render_boards(
    boards: Sequence[tuple[Any, NDArray[np.float64]]],
    intr: Intrinsics,
    settings: RenderSettings | None = None,
    rng: np.random.Generator | None = None,
) -> NDArray[np.uint8]:
    """Render one or more ChArUco boards seen by a pinhole camera.

    Args:
        boards: ``(spec, T_cam_board)`` pairs; ``T_cam_board`` maps board points (metres) into
            the camera optical frame (+z forward, +x right, +y down).
        intr: camera intrinsics (distortion is ignored: the render is ideal pinhole).
        settings: image-formation settings.
        rng: random generator for the background and the noise (seed it for repeatable renders).

    Returns:
        A BGR uint8 image of ``intr.height × intr.width``.

    Raises:
        CellError: a board is behind the camera or seen from its back.
    """
    s = settings or RenderSettings()
    rng = rng if rng is not None else np.random.default_rng(0)
    f = max(1, int(s.supersample))
    W, H = intr.width * f, intr.height * f
    Ks = np.array([[intr.fx * f, 0, intr.cx * f + (f - 1) / 2], [0, intr.fy * f, intr.cy * f + (f - 1) / 2], [0, 0, 1]])
    # Background: a smooth low-contrast texture (a steel bin side), generated small and upscaled.
    bg = rng.normal(0.0, 1.0, (max(4, intr.height // 40), max(4, intr.width // 40))).astype(np.float32)
    bg = cv2.resize(cv2.GaussianBlur(bg, (0, 0), 1.0), (W, H), interpolation=cv2.INTER_CUBIC)
    radiance = np.clip(s.background + 0.05 * bg, 0.0, 1.0)
    for spec, T in boards:
        T = np.asarray(T, dtype=np.float64)
        outline = board_outline(spec, 0.5)
        Pc = (T[:3, :3] @ outline.T).T + T[:3, 3]
        if np.any(Pc[:, 2] <= 0.02):
            raise CellError(f"board is (partly) behind the camera: outline z = {Pc[:, 2].round(3).tolist()} m")
        if T[2, 2] <= 0.0:
            raise CellError(f"board is seen from its back: board +z in camera = {T[:3, 2].round(3).tolist()}")
        # Texture resolution just above the largest projected square (supersampled pixels).
        sq_px = Ks[0, 0] * spec.square_m / float(Pc[:, 2].min())
        px = int(np.clip(2 ** np.ceil(np.log2(max(sq_px, 1.0) * 1.5)), 16, 512))
        tex = _texture(_spec_key(spec), px)
        margin = px // 2
        sc = spec.square_m / px
        # texture pixel centre (u, v) → board metric (x, y): x = (u + 0.5 - margin) * sc
        S = np.array([[sc, 0, (0.5 - margin) * sc], [0, sc, (0.5 - margin) * sc], [0, 0, 1]])
        Hm = Ks @ np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]]) @ S
        # Replicated border for the albedo, coverage from a warped mask: edges blend correctly.
        albedo = cv2.warpPerspective(tex, Hm, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        # Coverage: the projected outline (quiet zone included) filled at 1/16-pixel precision;
        # the supersampling turns its hard edge into partial coverage.
        corners_s = (Ks @ Pc.T).T
        poly = np.rint(corners_s[:, :2] / corners_s[:, 2:] * 16).astype(np.int32)
        mask = np.zeros((H, W), np.float32)
        cv2.fillConvexPoly(mask, poly, 1.0, lineType=cv2.LINE_8, shift=4)
        board_rad = s.black + (s.white - s.black) * albedo
        radiance = mask * board_rad + (1.0 - mask) * radiance
    # Box filter down to the final resolution (anti-aliasing).
    img = cv2.resize(radiance.astype(np.float32), (intr.width, intr.height), interpolation=cv2.INTER_AREA)
    yy, xx = np.mgrid[0 : intr.height, 0 : intr.width].astype(np.float32)
    ang = rng.uniform(0, 2 * np.pi)
    ramp = np.cos(ang) * (xx / intr.width - 0.5) + np.sin(ang) * (yy / intr.height - 0.5)
    img = img * (1.0 - s.light_gradient * (ramp + 0.5)) * s.exposure * 255.0
    if s.blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), s.blur_sigma)
    if s.motion_blur_px > 0:
        L = int(np.ceil(s.motion_blur_px)) | 1
        k = np.zeros((L, L), np.float32)
        c = L // 2
        d = np.array([np.cos(np.radians(s.motion_angle_deg)), np.sin(np.radians(s.motion_angle_deg))])
        for t in np.linspace(-s.motion_blur_px / 2, s.motion_blur_px / 2, 4 * L):
            k[int(round(c + t * d[1])), int(round(c + t * d[0]))] += 1.0
        img = cv2.filter2D(img, -1, k / k.sum())
    if s.noise_sigma > 0:
        img = img + rng.normal(0.0, s.noise_sigma, img.shape).astype(np.float32)
    grey = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)


def view_of_board(
    spec: Any,
    intr: Intrinsics,
    distance_m: float,
    tilt_deg: float = 0.0,
    tilt_axis_deg: float = 0.0,
    roll_deg: float = 0.0,
    offset_px: tuple[float, float] = (0.0, 0.0),
) -> NDArray[np.float64]:
    """``T_cam_board`` of a camera seeing the board centre at a given distance and angle.

    Args:
        spec: the board spec.
        intr: camera intrinsics (for the pixel offset).
        distance_m: camera centre to board centre, metres.
        tilt_deg: angle between the board normal and the optical axis, degrees.
        tilt_axis_deg: direction of the tilt axis in the board plane, degrees from board +x.
        roll_deg: rotation of the board about the optical axis, degrees.
        offset_px: where the board centre appears, pixels from the principal point.
    """
    from cellctl.geometry.transforms import rotation_about, transform_from

    a = np.radians(tilt_axis_deg)
    R = rotation_about((0.0, 0.0, 1.0), np.radians(roll_deg)) @ rotation_about(
        (np.cos(a), np.sin(a), 0.0), np.radians(tilt_deg)
    )
    ray = np.array([offset_px[0] / intr.fx, offset_px[1] / intr.fy, 1.0])
    ray /= np.linalg.norm(ray)
    c = np.array([spec.squares_x * spec.square_m / 2.0, spec.squares_y * spec.square_m / 2.0, 0.0])
    return transform_from(R, distance_m * ray - R @ c)


def random_view(
    spec: Any,
    intr: Intrinsics,
    distance_m: float,
    rng: np.random.Generator,
    max_tilt_deg: float = 40.0,
    max_roll_deg: float = 15.0,
    max_offset_frac: float = 0.15,
) -> NDArray[np.float64]:
    """A random :func:`view_of_board`: tilt uniform in [0, max], axis uniform, roll and offset uniform."""
    return view_of_board(
        spec,
        intr,
        distance_m,
        tilt_deg=float(rng.uniform(0.0, max_tilt_deg)),
        tilt_axis_deg=float(rng.uniform(0.0, 360.0)),
        roll_deg=float(rng.uniform(-max_roll_deg, max_roll_deg)),
        offset_px=(
            float(rng.uniform(-1, 1) * max_offset_frac * intr.width),
            float(rng.uniform(-1, 1) * max_offset_frac * intr.height),
        ),
    )
