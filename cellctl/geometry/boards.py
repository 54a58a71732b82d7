"""ChArUco boards of the bin catalog: the cv2 board object and its printable image.

The vision engineer detects boards with the object :func:`make_charuco_board` returns, and
the twin renders the image :func:`board_image` returns, so both sides agree on the layout
and the marker ids (``spec.first_id ..``). OpenCV is imported lazily.

Board frame (OpenCV ≥ 4.7): origin at the top-left outer corner, +x right, +y down, +z into
the board. The image row 0 is the board's top edge (y = 0), column 0 its left edge (x = 0).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import ConfigError
from cellctl.geometry.catalog import BoardSpec

__all__ = ["board_image", "make_charuco_board"]


def make_charuco_board(spec: BoardSpec) -> Any:
    """The ``cv2.aruco.CharucoBoard`` of ``spec`` with marker ids ``spec.ids``.

    Raises:
        ConfigError: the dictionary name is unknown or too small for the id range.
    """
    import cv2

    aruco = cv2.aruco
    dict_id = getattr(aruco, spec.dictionary, None)
    if dict_id is None:
        raise ConfigError(f"ArUco dictionary {spec.dictionary!r} does not exist in cv2.aruco")
    dictionary = aruco.getPredefinedDictionary(dict_id)
    n_dict = dictionary.bytesList.shape[0]
    if spec.ids.stop > n_dict:
        raise ConfigError(
            f"board ids {spec.ids.start}..{spec.ids.stop - 1} exceed dictionary {spec.dictionary} ({n_dict} markers)"
        )
    ids = np.arange(spec.ids.start, spec.ids.stop, dtype=np.int32)
    size = (spec.squares_x, spec.squares_y)
    board = aruco.CharucoBoard(size, spec.square_m, spec.marker_m, dictionary, ids)
    board.setLegacyPattern(spec.legacy_pattern)
    return board


def board_image(spec: BoardSpec, px_per_square: int = 100) -> NDArray[np.uint8]:
    """Greyscale image of the board with no margin: ``(squares_y*px, squares_x*px)`` uint8."""
    if px_per_square < 10:
        raise ConfigError(f"px_per_square {px_per_square} is too small; expected >= 10")
    board = make_charuco_board(spec)
    size = (spec.squares_x * px_per_square, spec.squares_y * px_per_square)
    img = board.generateImage(size, marginSize=0, borderBits=1)
    return np.asarray(img, dtype=np.uint8)
