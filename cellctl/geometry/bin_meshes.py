"""Parametric bin meshes for the catalog (``cellctl bins generate``).

A bin is a thin-walled shell swept along a star-shaped outline (rectangle or circle):

* a **body** of sections ``(z, sx, sy)`` from the top (z = 0) down, each the outline scaled
  by ``(sx, sy)`` — a straight wall is two equal sections, a hopper a shrinking one;
* a **top plate** from the outline in to a **hole** (a circle, or the outline inset by a
  margin = an open top);
* a **bottom plate** closing the last section; optional square **legs**.

Every surface exists twice, ``thickness`` apart: the outside (tag ``external``, brushed)
and the inside (tag ``internal``, polished) with normals pointing into the cavity. Faces are
oriented so their normals point away from the metal. Frame: origin at the centre of the top
opening, +Z up (ARCHITECTURE §5).

The case-study bin follows the paper (1030 mm high, 880 × 740 mm footprint, circular upper
hole, hopper-like lower part, legs) and carries the board at the paper's ``tag_H_bin``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import ConfigError
from cellctl.geometry.catalog import BoardSpec, T_tag_board, write_ply
from cellctl.geometry.transforms import invert, transform_from
from cellctl.hashing import file_sha256
from cellctl.surface import EXTERNAL, INTERNAL

__all__ = ["BinDesign", "DESIGNS", "build_mesh", "generate_catalog", "paper_tag_T_bin"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

PAPER_TAG_H_BIN = np.array(
    [
        [0.9997, -0.0233, 0.0105, 0.0277],
        [-0.0095, 0.0391, 0.9992, 0.1491],
        [-0.0237, -0.999, 0.0388, -0.3838],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
"""Paper Table 1 ``tag_H_bin`` as printed (4 decimals, so not exactly orthonormal)."""


def paper_tag_T_bin() -> NDArray[np.float64]:
    """Table 1 ``tag_H_bin`` with its rotation snapped to the nearest proper rotation (SVD)."""
    U, _, Vt = np.linalg.svd(PAPER_TAG_H_BIN[:3, :3])
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    return transform_from(R, PAPER_TAG_H_BIN[:3, 3])


@dataclass(frozen=True)
class BinDesign:
    """Parameters of one generated bin type (metres)."""

    name: str
    description: str
    outline: str  # "rect" or "circle"
    half_x: float  # rect half-width along x, or circle radius
    half_y: float  # rect half-depth along y (ignored for circles)
    sections: tuple[tuple[float, float, float], ...]  # (z, sx, sy), z from 0 downwards
    hole: tuple[str, float]  # ("circle", radius) or ("inset", margin)
    thickness: float = 0.004
    legs: tuple[tuple[float, float], ...] = ()  # leg centres (x, y)
    leg_size: float = 0.05
    leg_top_z: float = 0.0
    height: float = 1.0  # floor to top; legs reach the floor
    board_first_id: int = 0
    board_centre: tuple[float, float] = (0.0, -0.15)  # (x, z) of the board centre on the -y side
    board_standoff: float = 0.012
    tag_T_bin: tuple[tuple[float, ...], ...] | None = None  # overrides the board placement
    n_perimeter: int = 64
    row_spacing: float = 0.1
    top_rings: int = 5
    squares: tuple[int, int] = (7, 5)
    square_m: float = 0.04
    marker_m: float = 0.03
    extra: dict = field(default_factory=dict)

    def hole_radius(self) -> float:
        """Radius of the largest circle inside the top opening."""
        kind, v = self.hole
        if kind == "circle":
            return v
        r = self.half_x if self.outline == "circle" else min(self.half_x, self.half_y)
        return r - v

    def board_spec(self) -> tuple[BoardSpec, NDArray[np.float64] | None]:
        """The board and, for the case study, its tag_T_bin."""
        sx, sy = self.squares
        w, h = sx * self.square_m, sy * self.square_m
        proto = BoardSpec(
            squares_x=sx,
            squares_y=sy,
            square_m=self.square_m,
            marker_m=self.marker_m,
            first_id=self.board_first_id,
            T_bin_board=np.eye(4).tolist(),
        )
        if self.tag_T_bin is not None:
            tag_T_bin = np.asarray(self.tag_T_bin, dtype=np.float64)
            T = invert(tag_T_bin) @ T_tag_board(proto)
        else:
            tag_T_bin = None
            # Board upright on the -y side, facing -y: board x = bin +x, board y (down) = bin -z,
            # board z (into the board) = bin +y.
            R = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
            y_face = -(self.half_x if self.outline == "circle" else self.half_y) - self.board_standoff
            cx, cz = self.board_centre
            T = transform_from(R, [cx - w / 2, y_face, cz + h / 2])
        return proto.model_copy(update={"T_bin_board": T.tolist()}), tag_T_bin


# --- outline sampling ------------------------------------------------------------------------


def _outline(d: BinDesign) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Perimeter points (N, 2) at unit section scale, CCW, corners included; and 2-D outward normals."""
    n = d.n_perimeter
    if d.outline == "circle":
        a = np.linspace(0, 2 * np.pi, n, endpoint=False)
        P = d.half_x * np.stack([np.cos(a), np.sin(a)], 1)
        return P, np.stack([np.cos(a), np.sin(a)], 1)
    if d.outline != "rect":
        raise ConfigError(f"bin {d.name!r}: outline {d.outline!r} unknown; expected 'rect' or 'circle'")
    hx, hy = d.half_x, d.half_y
    corners = np.array([[hx, -hy], [hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    normals_edge = np.array([[1.0, 0], [0, 1.0], [-1.0, 0], [0, -1.0]])
    perim = 4 * (hx + hy)
    pts, nrm = [], []
    for k in range(4):
        a, b = corners[k], corners[k + 1]
        m = max(2, int(round(n * np.linalg.norm(b - a) / perim)))
        for i in range(m):
            pts.append(a + (b - a) * i / m)
            if i == 0:  # corner: mean of the two edge normals, scaled so the offset is exact
                nrm.append(normals_edge[k] + normals_edge[k - 1])
            else:
                nrm.append(normals_edge[k])
    return np.array(pts), np.array(nrm, dtype=np.float64)


def _orient(V: NDArray[np.float64], F: NDArray[np.int64], ref: NDArray[np.float64]) -> NDArray[np.int64]:
    """Flip faces whose normal points against ``ref`` (one direction per face)."""
    tri = V[F]
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    flip = np.einsum("ij,ij->i", nrm, ref) < 0
    F = F.copy()
    F[flip] = F[flip][:, [0, 2, 1]]
    return F


class _Builder:
    def __init__(self) -> None:
        self.V: list[NDArray[np.float64]] = []
        self.F: list[NDArray[np.int64]] = []
        self.S: list[NDArray[np.uint8]] = []
        self.n = 0

    def grid(self, rows: NDArray[np.float64], tag: int, ref_fn) -> None:
        """Add a closed-loop strip: ``rows`` (R, N, 3); quads between consecutive rows wrap around N."""
        R, N, _ = rows.shape
        idx = np.arange(R * N).reshape(R, N) + self.n
        F = []
        for r in range(R - 1):
            a, b = idx[r], idx[r + 1]
            a2, b2 = np.roll(a, -1), np.roll(b, -1)
            F.append(np.stack([a, b, b2], 1))
            F.append(np.stack([a, b2, a2], 1))
        self._add(rows.reshape(-1, 3), np.concatenate(F), tag, ref_fn)

    def fan(self, ring: NDArray[np.float64], centre: NDArray[np.float64], tag: int, ref_fn) -> None:
        N = len(ring)
        i = np.arange(N) + self.n
        c = self.n + N
        F = np.stack([i, np.roll(i, -1), np.full(N, c)], 1)
        self._add(np.vstack([ring, centre[None]]), F, tag, ref_fn)

    def mesh(self, V: NDArray[np.float64], F: NDArray[np.int64], tag: int, ref_fn) -> None:
        self._add(V, F + self.n, tag, ref_fn)

    def _add(self, V: NDArray[np.float64], F: NDArray[np.int64], tag: int, ref_fn) -> None:
        allV = np.vstack(self.V + [V]) if self.V else V
        centroids = allV[F].mean(axis=1)
        F = _orient(allV, F, ref_fn(centroids))
        self.V.append(V)
        self.F.append(F)
        self.S.append(np.full(len(F), tag, dtype=np.uint8))
        self.n += len(V)

    def result(self) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.uint8]]:
        return np.vstack(self.V), np.vstack(self.F), np.concatenate(self.S)


def _radial(c: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.stack([c[:, 0], c[:, 1], np.zeros(len(c))], 1)


def build_mesh(d: BinDesign) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.uint8]]:
    """Vertices (V, 3), faces (F, 3) and surface tags (F,) of a design, in the bin frame."""
    P, Nrm = _outline(d)
    t = d.thickness
    b = _Builder()
    up = lambda c: np.tile([0.0, 0.0, 1.0], (len(c), 1))  # noqa: E731
    down = lambda c: np.tile([0.0, 0.0, -1.0], (len(c), 1))  # noqa: E731
    outward = _radial
    inward = lambda c: -_radial(c)  # noqa: E731

    def ring(z: float, sx: float, sy: float, offset: float) -> NDArray[np.float64]:
        xy = P * [sx, sy] - offset * Nrm
        return np.column_stack([xy, np.full(len(P), z)])

    # body walls, outer and inner
    outer_rows, inner_rows = [], []
    secs = d.sections
    for k in range(len(secs) - 1):
        (z0, sx0, sy0), (z1, sx1, sy1) = secs[k], secs[k + 1]
        m = max(1, int(np.ceil(abs(z0 - z1) / d.row_spacing)))
        for i in range(m + (1 if k == len(secs) - 2 else 0)):
            f = i / m
            z, sx, sy = z0 + f * (z1 - z0), sx0 + f * (sx1 - sx0), sy0 + f * (sy1 - sy0)
            outer_rows.append(ring(z, sx, sy, 0.0))
            last = k == len(secs) - 2 and i == m
            zi = -t if (k == 0 and i == 0) else (z1 + t if last else z)
            inner_rows.append(ring(zi, sx, sy, t))
    b.grid(np.array(outer_rows), EXTERNAL, outward)
    b.grid(np.array(inner_rows), INTERNAL, inward)

    # top plate (annulus from the outline to the hole), outer (z=0) and inner (z=-t)
    kind, hv = d.hole
    sx0, sy0 = secs[0][1], secs[0][2]
    if kind == "circle":
        ang = np.arctan2(P[:, 1], P[:, 0])
        H = hv * np.stack([np.cos(ang), np.sin(ang)], 1)
    elif kind == "inset":
        H = P * [sx0, sy0] - hv * Nrm
    else:
        raise ConfigError(f"bin {d.name!r}: hole kind {kind!r} unknown; expected 'circle' or 'inset'")
    for z, off, tag, ref in ((0.0, 0.0, EXTERNAL, up), (-t, t, INTERNAL, down)):
        outer_xy = P * [sx0, sy0] - off * Nrm
        rows = []
        for i in range(d.top_rings + 1):
            f = i / d.top_rings
            xy = outer_xy + f * (H - outer_xy)
            rows.append(np.column_stack([xy, np.full(len(P), z)]))
        b.grid(np.array(rows), tag, ref)
    # hole rim: a strip of height t facing the hole's axis
    rim = np.array([np.column_stack([H, np.full(len(P), 0.0)]), np.column_stack([H, np.full(len(P), -t)])])
    b.grid(rim, EXTERNAL, inward)

    # bottom plate, outer (facing down) and inner (facing up)
    zb, sxb, syb = secs[-1]
    b.fan(ring(zb, sxb, syb, 0.0), np.array([0.0, 0.0, zb]), EXTERNAL, down)
    b.fan(ring(zb + t, sxb, syb, t), np.array([0.0, 0.0, zb + t]), INTERNAL, up)

    # legs: square boxes down to the floor (external)
    for lx, ly in d.legs:
        s = d.leg_size / 2
        z0, z1 = -d.height, d.leg_top_z
        corners = np.array(
            [[lx + dx * s, ly + dy * s, z] for z in (z0, z1) for dx, dy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        )
        quads = [(0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7), (4, 5, 6, 7), (0, 3, 2, 1)]
        F = np.array([tri for a, b_, c, e in quads for tri in ((a, b_, c), (a, c, e))], dtype=np.int64)
        centre = np.array([lx, ly, (z0 + z1) / 2])
        b.mesh(corners, F, EXTERNAL, lambda c, centre=centre: c - centre)
    return b.result()


def _case_study() -> BinDesign:
    hx, hy = 0.44, 0.37
    return BinDesign(
        name="case_study",
        description="paper case study: 880x740 mm body, circular top hole, hopper, four legs, 1030 mm high",
        outline="rect",
        half_x=hx,
        half_y=hy,
        sections=((0.0, 1.0, 1.0), (-0.45, 1.0, 1.0), (-0.78, 0.125 / hx, 0.125 / hy)),
        hole=("circle", 0.25),
        legs=tuple((sx * (hx - 0.035), sy * (hy - 0.035)) for sx in (-1, 1) for sy in (-1, 1)),
        leg_size=0.05,
        leg_top_z=-0.45,
        height=1.03,
        board_first_id=0,
        tag_T_bin=tuple(map(tuple, paper_tag_T_bin().tolist())),
        n_perimeter=64,
        row_spacing=0.08,
        top_rings=5,
    )


def _drum() -> BinDesign:
    return BinDesign(
        name="drum",
        description="cylindrical drum, 600 mm diameter, 850 mm high, wide lidless top with a 40 mm lip",
        outline="circle",
        half_x=0.30,
        half_y=0.30,
        sections=((0.0, 1.0, 1.0), (-0.85, 1.0, 1.0)),
        hole=("circle", 0.26),
        height=0.85,
        board_first_id=17,
        board_centre=(0.0, -0.22),
        board_standoff=0.02,
        n_perimeter=72,
        row_spacing=0.08,
        top_rings=3,
    )


def _tote() -> BinDesign:
    hx, hy = 0.60, 0.40
    return BinDesign(
        name="tote",
        description="low wide tote, 1200x800 mm, tapered walls, open top with a 40 mm rim, on four feet",
        outline="rect",
        half_x=hx,
        half_y=hy,
        sections=((0.0, 1.0, 1.0), (-0.55, 0.92, 0.9)),
        hole=("inset", 0.04),
        legs=tuple((sx * 0.45, sy * 0.27) for sx in (-1, 1) for sy in (-1, 1)),
        leg_size=0.08,
        leg_top_z=-0.55,
        height=0.63,
        board_first_id=34,
        board_centre=(0.15, -0.16),
        board_standoff=0.03,
        n_perimeter=80,
        row_spacing=0.07,
        top_rings=3,
    )


DESIGNS: dict[str, BinDesign] = {d.name: d for d in (_case_study(), _drum(), _tote())}
"""The generated catalog: name → design."""


def generate_catalog(
    root: Path,
    mesh_dir: str = "models/bins",
    catalog: str = "config/bins.yaml",
    designs: dict[str, BinDesign] | None = None,
) -> Path:
    """Write every design's PLY mesh and board PNG, then the catalog YAML with sha256 values.

    Returns:
        The catalog path.
    """
    import cv2
    import yaml

    from cellctl.geometry.boards import board_image

    designs = designs or DESIGNS
    out = Path(root) / mesh_dir
    out.mkdir(parents=True, exist_ok=True)
    entries = {}
    for d in designs.values():
        V, F, S = build_mesh(d)
        path = out / f"{d.name}.ply"
        write_ply(path, V, F, S)
        board, tag_T_bin = d.board_spec()
        cv2.imwrite(str(out / f"{d.name}_board.png"), board_image(board, 100))
        entry = {
            "description": d.description,
            "mesh": f"{mesh_dir}/{d.name}.ply",
            "mesh_sha256": file_sha256(path),
            "height_m": round(float(d.height), 6),
            "top_hole_radius_m": round(float(d.hole_radius()), 6),
            "board": {
                **board.model_dump(exclude={"T_bin_board"}),
                "T_bin_board": [[round(float(x), 9) for x in row] for row in board.T_bin_board],
            },
        }
        if tag_T_bin is not None:
            entry["tag_T_bin"] = [[round(float(x), 9) for x in row] for row in tag_T_bin]
        entries[d.name] = entry
        log.info("bin %s: %d faces (%d internal) → %s", d.name, len(F), int((S == INTERNAL).sum()), path)
    cat_path = Path(root) / catalog
    cat_path.parent.mkdir(parents=True, exist_ok=True)
    header = (
        "# Bin catalog, generated by `cellctl bins generate` (cellctl/geometry/bin_meshes.py).\n"
        "# Frames: see cellctl/geometry/catalog.py.\n"
        "# Board ids: first_id .. first_id + squares_x*squares_y//2 - 1.\n"
    )
    text = yaml.safe_dump({"bins": entries}, sort_keys=False, width=120, default_flow_style=None)
    cat_path.write_text(header + text)
    return cat_path
