"""The bin catalog: bin types, their meshes, and the ChArUco board that identifies each.

Light module (numpy, yaml, pydantic only): the supervisor imports it.

``config/bins.yaml`` lists bin types::

    bins:
      case_study:
        mesh: models/bins/case_study.ply      # PLY with a per-face ``surface`` property
        mesh_sha256: 3f0c…                    # sha256 of the mesh file bytes
        height_m: 1.03
        top_hole_radius_m: 0.25
        board: {squares_x: 7, squares_y: 5, square_m: 0.04, marker_m: 0.03,
                dictionary: DICT_5X5_1000, first_id: 0, T_bin_board: [[…4x4…]]}
        tag_T_bin: [[…4x4…]]                  # optional, paper Table 1 (case study only)

Frames (ARCHITECTURE §5):

* **bin** (mesh) frame: origin at the centre of the top opening, +Z up, so every vertex has
  ``z <= 0`` (up to a rim tolerance) and the opening centre lies inside the footprint.
* **board** frame (OpenCV ≥ 4.7 ChArUco convention): origin at the board's top-left outer
  corner, +x right along the squares, +y **down**, +z **into** the board (away from a
  camera that sees it). ``T_bin_board`` maps board points into the bin frame.
* **tag** frame (the paper's Table 1 ``tag_H_bin``, legacy ArUco marker convention): origin
  at the board's centre, +x right, +y **up**, +z **out of** the board. Hence
  ``T_tag_board = [Rx(pi) | (-W/2, H/2, 0)]`` with ``W = squares_x*square_m``,
  ``H = squares_y*square_m``, and ``T_bin_board = inv(tag_T_bin) @ T_tag_board``
  (see :func:`T_tag_board`).

A bin type is identified by its board's marker ids: ``first_id .. first_id + n_markers - 1``
with ``n_markers = squares_x * squares_y // 2``; id ranges of different types must not overlap.

Mesh face tags: each face is ``external`` (0, brushed outer surface) or ``internal`` (1,
polished inner surface). PLY files carry them as a face property ``uchar surface``; any
other mesh format trimesh can read is accepted with a sidecar ``<mesh>.surface.npy`` (int
array, one tag per face) or, without one, every face is external.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, ValidationError, field_validator, model_validator

from cellctl.errors import CellError, ConfigError
from cellctl.geometry.transforms import check_transform, invert, transform_from
from cellctl.hashing import file_sha256
from cellctl.strict_model import FrozenConfigModel as _Model
from cellctl.surface import FACE_TAG, INTERNAL, SURFACES

__all__ = [
    "BinMesh",
    "BinType",
    "BoardSpec",
    "Catalog",
    "T_tag_board",
    "load_catalog",
    "read_bin_mesh",
    "read_ply",
    "write_ply",
]

FRAME_TOL_M = 0.02
"""How far above z = 0 a vertex may lie (rims, handles) and still follow the frame convention."""


def _as_transform(v: Any, name: str) -> list[list[float]]:
    try:
        T = check_transform(v, name)
    except CellError as err:
        raise ValueError(str(err)) from None
    return T.tolist()


class BoardSpec(_Model):
    """A ChArUco board: layout, dictionary, marker-id range and where it sits on the bin."""

    squares_x: int = Field(ge=2, le=40)
    squares_y: int = Field(ge=2, le=40)
    square_m: float = Field(gt=0, le=1.0, description="chessboard square side (m)")
    marker_m: float = Field(gt=0, le=1.0, description="ArUco marker side (m)")
    dictionary: str = "DICT_5X5_1000"
    first_id: int = Field(ge=0)
    legacy_pattern: bool = Field(default=False, description="cv2 setLegacyPattern; keep False for own boards")
    T_bin_board: list[list[float]] = Field(description="4x4: board frame → bin frame")

    @field_validator("T_bin_board")
    @classmethod
    def _T(cls, v: Any) -> list[list[float]]:
        return _as_transform(v, "T_bin_board")

    @field_validator("dictionary")
    @classmethod
    def _dict(cls, v: str) -> str:
        if not v.startswith("DICT_"):
            raise ValueError(f"dictionary {v!r} is not an OpenCV dictionary name like 'DICT_5X5_1000'")
        return v

    @model_validator(mode="after")
    def _marker_fits(self) -> BoardSpec:
        if self.marker_m >= self.square_m:
            raise ValueError(f"marker_m {self.marker_m} must be smaller than square_m {self.square_m}")
        return self

    @property
    def n_markers(self) -> int:
        """Markers on the board (the white squares): ``squares_x * squares_y // 2``."""
        return self.squares_x * self.squares_y // 2

    @property
    def ids(self) -> range:
        """Marker ids printed on this board, in board order."""
        return range(self.first_id, self.first_id + self.n_markers)

    @property
    def size_m(self) -> tuple[float, float]:
        """Board width (x) and height (y) in metres."""
        return self.squares_x * self.square_m, self.squares_y * self.square_m

    def T_bin_board_matrix(self) -> NDArray[np.float64]:
        return np.asarray(self.T_bin_board, dtype=np.float64)


def T_tag_board(board: BoardSpec) -> NDArray[np.float64]:
    """Board frame (OpenCV ChArUco, top-left, y down, z in) → tag frame (centre, y up, z out)."""
    w, h = board.size_m
    R = np.diag([1.0, -1.0, -1.0])  # Rx(pi)
    return transform_from(R, [-w / 2.0, h / 2.0, 0.0])


class BinType(_Model):
    """One bin type of the catalog."""

    name: str
    mesh: Path = Field(description="mesh file, relative paths are against the project root")
    mesh_sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    height_m: float = Field(gt=0, le=5.0)
    top_hole_radius_m: float = Field(gt=0, le=3.0, description="radius of the (inscribed) top opening")
    board: BoardSpec
    tag_T_bin: list[list[float]] | None = Field(
        default=None, description="paper Table 1 tag_H_bin: bin frame → tag frame (optional)"
    )
    description: str = ""

    @field_validator("tag_T_bin")
    @classmethod
    def _tag(cls, v: Any) -> list[list[float]] | None:
        return None if v is None else _as_transform(v, "tag_T_bin")

    @model_validator(mode="after")
    def _tag_consistent(self) -> BinType:
        if self.tag_T_bin is not None:
            expected = invert(np.asarray(self.tag_T_bin)) @ T_tag_board(self.board)
            err = float(np.abs(expected - self.board.T_bin_board_matrix()).max())
            if err > 1e-6:
                raise ValueError(
                    f"board.T_bin_board disagrees with inv(tag_T_bin) @ T_tag_board by {err:.3g} "
                    "(they must describe the same board placement)"
                )
        return self

    def T_bin_board(self) -> NDArray[np.float64]:
        return self.board.T_bin_board_matrix()


@dataclass(frozen=True, eq=False)
class BinMesh:
    """A bin mesh in its bin frame: the one bin-mesh type of the catalog, the twin and the planner.

    The derived per-face arrays are computed once, on construction (the planner reads them
    in every stage). ``eq=False``: meshes compare (and hash) by identity, arrays have no
    truth value.

    Attributes:
        vertices: (V, 3) float64, metres, bin frame.
        faces: (F, 3) int64 vertex indices, counter-clockwise seen from the side the normal points to.
        surface: (F,) uint8, :data:`EXTERNAL` or :data:`INTERNAL` per face.
        name: bin type or file name.
        sha256: hash of the mesh file (or of the arrays of a generated mesh); "" when unknown.
        watertight: every edge is shared by exactly two faces; None when not checked.
        normals: (F, 3) unit normals (derived).
        areas: (F,) m² (derived).
        centroids: (F, 3) m (derived).
    """

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    surface: NDArray[np.uint8]
    name: str = "mesh"
    sha256: str = ""
    watertight: bool | None = None
    normals: NDArray[np.float64] = field(init=False, repr=False)
    areas: NDArray[np.float64] = field(init=False, repr=False)
    centroids: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        v = self.vertices[self.faces]
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        object.__setattr__(self, "normals", n / np.maximum(length, 1e-300))
        object.__setattr__(self, "areas", 0.5 * length[:, 0])
        object.__setattr__(self, "centroids", v.mean(axis=1))

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    @property
    def internal(self) -> NDArray[np.bool_]:
        """(F,) True for faces of the internal surface (inside the container)."""
        return np.asarray(self.surface == INTERNAL)

    def surface_mask(self, surface: str) -> NDArray[np.bool_]:
        """(F,) True for the faces of ``surface`` ("external" or "internal").

        Raises:
            ConfigError: an unknown surface name.
        """
        if surface not in SURFACES:
            raise ConfigError(f"surface {surface!r} is unknown; expected one of {sorted(SURFACES)}")
        return np.asarray(self.surface == FACE_TAG[surface])

    def to_trimesh(self):  # trimesh.Trimesh, imported lazily
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)


# --- PLY ------------------------------------------------------------------------------------


def write_ply(
    path: Path | str, vertices: NDArray[np.floating], faces: NDArray[np.integer], surface: NDArray[np.integer]
) -> None:
    """Write an ASCII PLY with a per-face ``uchar surface`` property (deterministic bytes)."""
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    S = np.asarray(surface, dtype=np.int64)
    lines = [
        "ply",
        "format ascii 1.0",
        "comment cellctl bin mesh: metres, bin frame (origin at top-opening centre, +Z up)",
        "comment face surface: 0 = external (brushed), 1 = internal (polished)",
        f"element vertex {len(V)}",
        "property float64 x",
        "property float64 y",
        "property float64 z",
        f"element face {len(F)}",
        "property list uchar int vertex_indices",
        "property uchar surface",
        "end_header",
    ]
    lines += [f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in V]
    lines += [f"3 {a} {b} {c} {s}" for (a, b, c), s in zip(F, S, strict=True)]
    Path(path).write_text("\n".join(lines) + "\n")


def read_ply(path: Path | str) -> BinMesh:
    """Read an ASCII PLY written by :func:`write_ply` (triangles, optional ``surface``).

    Raises:
        ConfigError: the file is not such a PLY or its contents are inconsistent.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"mesh {str(p)!r} cannot be read as ASCII PLY: {err}") from err
    head, sep, body = text.partition("end_header\n")
    if not sep or not head.startswith("ply") or "format ascii 1.0" not in head:
        raise ConfigError(f"mesh {str(p)!r} is not an ASCII PLY (expected 'ply' / 'format ascii 1.0' header)")
    n_v = n_f = None
    face_props: list[str] = []
    in_face = False
    for line in head.splitlines():
        parts = line.split()
        if parts[:2] == ["element", "vertex"]:
            n_v, in_face = int(parts[2]), False
        elif parts[:2] == ["element", "face"]:
            n_f, in_face = int(parts[2]), True
        elif parts[:1] == ["property"] and in_face:
            face_props.append(parts[-1])
    if n_v is None or n_f is None or not face_props or face_props[0] != "vertex_indices":
        raise ConfigError(f"mesh {str(p)!r}: PLY header lacks vertex/face elements")
    rows = body.splitlines()
    if len(rows) < n_v + n_f:
        raise ConfigError(f"mesh {str(p)!r} is truncated: {len(rows)} data lines, expected {n_v + n_f}")
    try:
        V = np.array([r.split()[:3] for r in rows[:n_v]], dtype=np.float64)
        frows = [r.split() for r in rows[n_v : n_v + n_f]]
        if any(r[0] != "3" for r in frows):
            raise ConfigError(f"mesh {str(p)!r}: only triangle faces are supported")
        F = np.array([r[1:4] for r in frows], dtype=np.int64)
        S = (
            np.array([r[4] for r in frows], dtype=np.uint8)
            if "surface" in face_props
            else np.zeros(n_f, dtype=np.uint8)
        )
    except (ValueError, IndexError) as err:
        raise ConfigError(f"mesh {str(p)!r} has malformed data lines: {err}") from err
    if V.shape != (n_v, 3) or not np.all(np.isfinite(V)):
        raise ConfigError(f"mesh {str(p)!r}: vertices must be finite (N, 3)")
    if F.size and (F.min() < 0 or F.max() >= n_v):
        raise ConfigError(f"mesh {str(p)!r}: face indices outside 0..{n_v - 1}")
    return BinMesh(V, F, S)


def read_bin_mesh(path: Path | str) -> BinMesh:
    """Read a bin mesh of any trimesh-readable format; PLY keeps its ``surface`` tags.

    Raises:
        ConfigError: missing, unreadable or empty file, or bad surface tags.
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"mesh file {str(p)!r} does not exist")
    if p.suffix.lower() == ".ply":
        with open(p, "rb") as f:
            ascii_ply = b"format ascii" in f.read(200)
        if ascii_ply:
            mesh = read_ply(p)
            _check_surface(mesh.surface, mesh.n_faces, p)
            return mesh
    try:
        import trimesh

        tm = trimesh.load(str(p), force="mesh", process=False)
    except Exception as err:  # trimesh raises many kinds for corrupt files
        raise ConfigError(f"mesh {str(p)!r} cannot be loaded: {err}") from err
    V = np.asarray(tm.vertices, dtype=np.float64)
    F = np.asarray(tm.faces, dtype=np.int64)
    if len(F) == 0:
        raise ConfigError(f"mesh {str(p)!r} has no faces")
    side = p.with_suffix(p.suffix + ".surface.npy")
    S = np.load(side).astype(np.uint8) if side.is_file() else np.zeros(len(F), dtype=np.uint8)
    _check_surface(S, len(F), p)
    return BinMesh(V, F, S)


def _check_surface(S: NDArray[np.uint8], n_faces: int, p: Path) -> None:
    if S.shape != (n_faces,):
        raise ConfigError(f"mesh {str(p)!r}: {S.shape[0]} surface tags for {n_faces} faces")
    bad = set(np.unique(S).tolist()) - set(FACE_TAG.values())
    if bad:
        raise ConfigError(f"mesh {str(p)!r}: surface tags {sorted(bad)} unknown; expected {FACE_TAG}")


def check_frame_convention(mesh: BinMesh, name: str, height_m: float | None = None) -> None:
    """Raise ConfigError unless the mesh follows the bin frame convention (ARCHITECTURE §5)."""
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    if not (-FRAME_TOL_M <= hi[2] <= FRAME_TOL_M):
        raise ConfigError(
            f"bin {name!r}: mesh top is at z = {hi[2]:.3f} m; expected ~0 (origin at the top opening, +Z up)"
        )
    if not (lo[0] < 0 < hi[0] and lo[1] < 0 < hi[1]):
        raise ConfigError(
            f"bin {name!r}: origin (0, 0) lies outside the mesh footprint x [{lo[0]:.3f}, {hi[0]:.3f}], "
            f"y [{lo[1]:.3f}, {hi[1]:.3f}]; expected the origin at the centre of the top opening"
        )
    if height_m is not None and abs((hi[2] - lo[2]) - height_m) > 0.02:
        raise ConfigError(f"bin {name!r}: mesh is {hi[2] - lo[2]:.3f} m high but height_m says {height_m:.3f} m")


# --- catalog --------------------------------------------------------------------------------


class _CatalogFile(_Model):
    bins: dict[str, dict[str, Any]]


class Catalog:
    """The bin types of a cell, looked up by name or by a detected marker id.

    Args:
        types: the bin types.
        root: base of relative mesh paths.
    """

    def __init__(self, types: list[BinType], root: Path) -> None:
        self.root = Path(root)
        self._types = {t.name: t for t in types}
        self._meshes: dict[str, BinMesh] = {}
        ranges = sorted((t.board.ids.start, t.board.ids.stop - 1, t.name) for t in types)
        for (a0, a1, an), (b0, b1, bn) in zip(ranges, ranges[1:], strict=False):
            if b0 <= a1:
                raise ConfigError(
                    f"board id ranges overlap: {an!r} uses {a0}..{a1} and {bn!r} uses {b0}..{b1}; "
                    "each bin type needs its own marker-id range"
                )

    def __iter__(self) -> Iterator[BinType]:
        return iter(self._types.values())

    def __len__(self) -> int:
        return len(self._types)

    def __contains__(self, name: object) -> bool:
        return name in self._types

    @property
    def names(self) -> list[str]:
        return list(self._types)

    def get(self, name: str) -> BinType:
        """The bin type called ``name``; ConfigError listing the known names otherwise."""
        try:
            return self._types[name]
        except KeyError:
            raise ConfigError(f"bin type {name!r} is unknown; the catalog has {self.names}") from None

    def by_marker_id(self, marker_id: int) -> BinType | None:
        """The bin type whose board carries ``marker_id``, or None if no board does."""
        for t in self._types.values():
            if int(marker_id) in t.board.ids:
                return t
        return None

    def mesh_path(self, name: str) -> Path:
        m = self.get(name).mesh
        return m if m.is_absolute() else self.root / m

    def load_mesh(self, name: str) -> BinMesh:
        """The bin's mesh (cached), checked against its sha256 and the frame convention."""
        if name not in self._meshes:
            t = self.get(name)
            path = self.mesh_path(name)
            if not path.is_file():
                raise ConfigError(f"bin {name!r}: mesh file {str(path)!r} does not exist")
            sha = file_sha256(path)
            if sha != t.mesh_sha256:
                raise ConfigError(f"bin {name!r}: mesh {str(path)!r} has sha256 {sha}, catalog expects {t.mesh_sha256}")
            mesh = read_bin_mesh(path)
            check_frame_convention(mesh, name, t.height_m)
            self._meshes[name] = mesh
        return self._meshes[name]


def load_catalog(path: Path | str, root: Path | str | None = None, verify_meshes: bool = True) -> Catalog:
    """Load and validate ``bins.yaml``.

    Args:
        path: the catalog YAML.
        root: base of relative mesh paths (default: the folder above ``config/``, else the file's folder).
        verify_meshes: check that each mesh exists and matches its sha256 (reads the files).

    Raises:
        ConfigError: malformed YAML, invalid fields, overlapping board id ranges, a missing
            mesh or a sha256 mismatch; the message names the bin, the value and what was expected.
    """
    from cellctl.config import explain_validation, safe_yaml_load

    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"bin catalog {str(p)!r} does not exist")
    try:
        data = safe_yaml_load(p.read_text(encoding="utf-8"), str(p))
    except UnicodeDecodeError as err:
        raise ConfigError(f"bin catalog {str(p)!r} is not a YAML text file (byte {err.start} is not UTF-8)") from None
    if not isinstance(data, dict) or "bins" not in data:
        # another YAML file (a cell config given as catalog): say so, not every key it holds
        top = sorted(data)[:5] if isinstance(data, dict) else type(data).__name__
        raise ConfigError(f"{str(p)!r} is not a bin catalog: expected a top-level 'bins' mapping, got {top}")
    try:
        parsed = _CatalogFile.model_validate(data)
    except ValidationError as err:
        raise ConfigError(explain_validation(err, _CatalogFile, str(p))) from err
    if root is None:
        parent = p.resolve().parent
        root = parent.parent if parent.name == "config" else parent
    types = []
    for name, body in parsed.bins.items():
        try:
            types.append(BinType.model_validate({**body, "name": name}))
        except ValidationError as err:
            raise ConfigError(explain_validation(err, BinType, f"{p} bin {name!r}")) from err
    if not types:
        raise ConfigError(f"bin catalog {str(p)!r} lists no bin types")
    cat = Catalog(types, Path(root))
    if verify_meshes:
        for t in types:
            path_m = cat.mesh_path(t.name)
            if not path_m.is_file():
                raise ConfigError(f"bin {t.name!r}: mesh file {str(path_m)!r} does not exist")
            sha = file_sha256(path_m)
            if sha != t.mesh_sha256:
                raise ConfigError(
                    f"bin {t.name!r}: mesh {str(path_m)!r} has sha256 {sha}, catalog expects {t.mesh_sha256}"
                )
    return cat
