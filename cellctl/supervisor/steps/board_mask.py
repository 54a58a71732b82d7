"""Hide the bin's own ID board from the classifier.

The ChArUco board is mounted on the bin's outer wall; its black-and-white pattern is not a
surface to inspect and looks like contamination to a clean/dirty classifier (seen in the
demo: a clean bin called dirty from the one viewpoint that sees the board). Its pose is
known, so its outline is projected into each image and filled with the median colour of the
rest of the frame before classification. The recorded image stays untouched.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cellctl.errors import CellError
from cellctl.geometry.transforms import invert
from cellctl.images import MAX_IMAGE_PIXELS, decode_image
from cellctl.messages import Intrinsics

__all__ = ["mask_board"]

MARGIN_M = 0.01
"""The board plate's edge around the printed pattern."""


def board_polygon(bin_type: Any, T_base_bin: np.ndarray, T_base_cam: np.ndarray, intr: Intrinsics) -> np.ndarray | None:
    """Pixel outline (4, 2) of the board in this view, or None when the camera cannot see its face.

    The board frame's +z points into the board (away from a camera that reads it), so a camera
    at z ≥ 0 in that frame looks at the board's back: through the wall it is mounted on, from
    inside the bin or past the wall's edge. Filling its outline there would paint a textureless
    rectangle over steel the camera does see, which the detector rightly calls a film (the
    bench's external false-dirty bins: 13 of 15 filled views in one clean cycle were such).
    """
    from cellctl.classify.heatmap import board_quad  # heatmap imports OpenCV; the gateway imports this module light

    T_cam_bin = invert(T_base_cam) @ np.asarray(T_base_bin)
    if invert(T_cam_bin @ bin_type.T_bin_board())[2, 3] >= 0.0:
        return None  # the board's back: the camera cannot see the pattern
    p = T_cam_bin[:3, :3] @ board_quad(bin_type, MARGIN_M).T + T_cam_bin[:3, 3:]
    if np.any(p[2] <= 0.01):
        return None
    uv: np.ndarray = intr.K() @ (p / p[2])
    return uv[:2].T


def mask_board(
    png: bytes,
    bin_type: Any,
    T_base_bin: np.ndarray,
    T_base_cam: np.ndarray,
    intr: Intrinsics,
    max_pixels: int = MAX_IMAGE_PIXELS,
) -> bytes:
    """The image with the board filled in, or the same bytes when its face is not in view.

    Args:
        max_pixels: the cell's pixel budget (``camera.max_image_pixels``): the mask decodes exactly
            what the classifier will, so a camera above the default budget is still masked and an
            image over the cell's budget is never decoded here.
    """
    import cv2

    poly = board_polygon(bin_type, T_base_bin, T_base_cam, intr)
    if poly is None:
        return png
    W, H = intr.width, intr.height
    if poly[:, 0].max() < 0 or poly[:, 0].min() > W or poly[:, 1].max() < 0 or poly[:, 1].min() > H:
        return png
    try:
        img = decode_image(png, "to mask", order="bgr", max_pixels=max_pixels)
    except CellError:
        return png  # not ours to judge: the classifier refuses what it cannot decode
    sx, sy = img.shape[1] / W, img.shape[0] / H
    pts = np.round(poly * [sx, sy]).astype(np.int32)
    mask = np.zeros(img.shape[:2], np.uint8)
    cv2.fillPoly(mask, [pts], 255)
    if mask.mean() > 0.9 * 255:
        return png  # nothing but board: leave it to the classifier's uncertainty
    fill = np.median(img[mask == 0], axis=0)
    img[mask > 0] = fill
    ok, out = cv2.imencode(".png", img)
    return out.tobytes() if ok else png
