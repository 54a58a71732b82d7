"""ChArUco boards of the bin catalog, as OpenCV objects and id ranges.

Every bin type carries one ChArUco board; boards share one ArUco dictionary and use
disjoint marker-id ranges (board ``k`` holds ids ``first_id .. first_id + N - 1`` with
``N = squares_x * squares_y // 2``), so one marker pass and an id lookup give the bin type.

Board frame (OpenCV's ``CharucoBoard`` object frame, the frame ``T_cam_board`` refers to):
origin at the top-left *outer* corner of the chessboard, +x along the rows (right), +y down
the columns, +z into the board (away from a camera that reads it). Units are metres.

The board spec is the catalog's :class:`cellctl.geometry.catalog.BoardSpec` (re-exported
here for the vision API). The functions are duck-typed: a "spec" is anything with the
attributes ``squares_x, squares_y, square_m, marker_m, dictionary, first_id`` and
optionally ``T_bin_board`` (4×4, maps board points into the bin frame).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.errors import ConfigError
from cellctl.geometry.catalog import BoardSpec

__all__ = [
    "BoardSpec",
    "KnownBoard",
    "board_centre",
    "boards_from_catalog",
    "get_dictionary",
    "make_board",
    "n_markers",
]


@dataclass(frozen=True)
class KnownBoard:
    """One catalog board ready for detection.

    Attributes:
        bin_type: the catalog name of the bin type carrying the board.
        spec: the board spec it was built from.
        board: the OpenCV ``CharucoBoard``.
        ids: (N,) marker ids of the board.
        T_bin_board: 4×4, board frame → bin frame.
    """

    bin_type: str
    spec: Any
    board: Any
    ids: NDArray[np.int32]
    T_bin_board: NDArray[np.float64]

    @property
    def id_range(self) -> tuple[int, int]:
        """Inclusive range of marker ids on this board."""
        return int(self.ids[0]), int(self.ids[-1])


def n_markers(spec: Any) -> int:
    """Number of ArUco markers on a ChArUco board: half the squares, rounded down."""
    return int(spec.squares_x) * int(spec.squares_y) // 2


def get_dictionary(name: Any) -> Any:
    """The OpenCV predefined ArUco dictionary named ``name`` (``"DICT_5X5_1000"``, ``"5X5_1000"`` or the int).

    Raises:
        ConfigError: the name is not an OpenCV predefined dictionary.
    """
    if isinstance(name, (int, np.integer)):
        return cv2.aruco.getPredefinedDictionary(int(name))
    key = str(name).upper()
    if not key.startswith("DICT_"):
        key = "DICT_" + key
    if not hasattr(cv2.aruco, key):
        known = sorted(k for k in dir(cv2.aruco) if k.startswith("DICT_"))
        raise ConfigError(f"ArUco dictionary {name!r} is unknown; expected one of {known}")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, key))


def _check_spec(spec: Any, where: str) -> None:
    for attr in ("squares_x", "squares_y", "square_m", "marker_m", "dictionary", "first_id"):
        if not hasattr(spec, attr):
            raise ConfigError(f"{where}: board spec {spec!r} has no attribute {attr!r}")
    if int(spec.squares_x) < 3 or int(spec.squares_y) < 3:
        raise ConfigError(f"{where}: board needs at least 3×3 squares, got {spec.squares_x}×{spec.squares_y}")
    if not 0 < float(spec.marker_m) < float(spec.square_m):
        raise ConfigError(
            f"{where}: marker_m {spec.marker_m} must be positive and smaller than square_m {spec.square_m}"
        )


def make_board(spec: Any) -> Any:
    """OpenCV ``CharucoBoard`` for ``spec`` with its own marker-id range.

    Args:
        spec: a board spec (see module docstring).

    Raises:
        ConfigError: the spec is malformed or its id range does not fit the dictionary.
    """
    _check_spec(spec, "board")
    dic = get_dictionary(spec.dictionary)
    n = n_markers(spec)
    first = int(spec.first_id)
    size = int(dic.bytesList.shape[0])
    if first < 0 or first + n > size:
        raise ConfigError(
            f"board ids {first}..{first + n - 1} do not fit dictionary {spec.dictionary!r} (ids 0..{size - 1})"
        )
    ids = np.arange(first, first + n, dtype=np.int32)
    board = cv2.aruco.CharucoBoard(
        (int(spec.squares_x), int(spec.squares_y)), float(spec.square_m), float(spec.marker_m), dic, ids
    )
    # Same layout as the printed/rendered board (cellctl.geometry.boards.make_charuco_board).
    board.setLegacyPattern(bool(getattr(spec, "legacy_pattern", False)))
    return board


def board_centre(spec: Any) -> NDArray[np.float64]:
    """Centre of the chessboard in the board frame, metres (3,)."""
    return np.array([spec.squares_x * spec.square_m / 2.0, spec.squares_y * spec.square_m / 2.0, 0.0])


def _iter_types(catalog: Any) -> Iterable[tuple[str, Any]]:
    """(name, spec) pairs from the many shapes a catalog may take."""
    if isinstance(catalog, KnownBoard):
        yield catalog.bin_type, catalog.spec
        return
    if hasattr(catalog, "board") and hasattr(catalog, "name"):  # a single BinType
        yield str(catalog.name), catalog.board
        return
    if isinstance(catalog, Mapping):
        items: Iterable[tuple[Any, Any]] = catalog.items()
    else:
        for attr in ("types", "bins", "bin_types"):
            inner = getattr(catalog, attr, None)
            if inner is not None and not callable(inner):
                yield from _iter_types(inner)
                return
        items = ((getattr(v, "name", None), v) for v in catalog)
    for name, value in items:
        if isinstance(value, KnownBoard):
            yield value.bin_type, value.spec
        elif hasattr(value, "board") and not hasattr(value, "squares_x"):  # a BinType
            yield str(getattr(value, "name", name)), value.board
        else:  # already a board spec
            yield str(name), value


def boards_from_catalog(catalog: Any) -> list[KnownBoard]:
    """Build detection boards for every bin type of ``catalog``.

    Args:
        catalog: a mapping ``name → BinType | BoardSpec``, an iterable of ``BinType`` (objects
            with ``.name`` and ``.board``), an object holding one of those as ``.types``/``.bins``,
            or a list of :class:`KnownBoard`.

    Returns:
        One :class:`KnownBoard` per bin type, in catalog order.

    Raises:
        ConfigError: empty catalog, two types with overlapping id ranges or different
            dictionaries, or a malformed board spec.
    """
    if isinstance(catalog, list) and catalog and all(isinstance(k, KnownBoard) for k in catalog):
        return catalog
    out: list[KnownBoard] = []
    for name, spec in _iter_types(catalog):
        _check_spec(spec, f"bin type {name!r}")
        board = make_board(spec)
        ids = np.asarray(board.getIds(), dtype=np.int32).ravel()
        T = np.asarray(getattr(spec, "T_bin_board", np.eye(4)), dtype=np.float64)
        if T.shape != (4, 4):
            raise ConfigError(f"bin type {name!r}: T_bin_board must be 4×4, got shape {T.shape}")
        out.append(KnownBoard(bin_type=name, spec=spec, board=board, ids=ids, T_bin_board=T))
    if not out:
        raise ConfigError(f"the bin catalog {catalog!r} holds no bin types with a board")
    dicts = {str(k.spec.dictionary) for k in out}
    if len(dicts) > 1:
        raise ConfigError(f"all catalog boards must share one ArUco dictionary, got {sorted(dicts)}")
    for i, a in enumerate(out):
        for b in out[i + 1 :]:
            lo = max(a.id_range[0], b.id_range[0])
            hi = min(a.id_range[1], b.id_range[1])
            if lo <= hi:
                raise ConfigError(
                    f"bin types {a.bin_type!r} (ids {a.id_range}) and {b.bin_type!r} (ids {b.id_range}) "
                    "share marker ids; expected disjoint id ranges"
                )
    return out
