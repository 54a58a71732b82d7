"""A parametric shape family of bins the planner was not tuned on (issue 35 item 1).

``cellctl geometry generate --family F --seed S --out mesh.stl`` draws one bin of family ``F``
from seed ``S`` (``numpy.random.default_rng([FAMILY_STREAM, family index, S])``) and writes it with
its per-face surface tags (``<out>.surface.npy``, the catalog's sidecar convention) and its
parameters (``<out>.json``). The same (family, seed) gives the same bytes.

A bin is built in named stages, each adding closed pieces to one mesh:

* :func:`outline` — the body's cross-section: a circle (cylindrical body), a regular polygon
  (5–8 sides) or a rectangle, with the offset directions that make a wall of exact thickness;
* :func:`body_sections` — the wall profile from the top (z = 0) down: straight, then a flat
  bottom, a dished (elliptic) bottom or a hopper (conical on a circle, pyramidal otherwise);
* :func:`add_shell` — the thin-walled shell: outer wall and bottom (``external``), inner wall
  and bottom (``internal``), the top plate outside (``external``) and its underside
  (``internal``), the opening's rim — a round or square opening, centred or off-centre, narrow or
  wide, or the whole top open (lid removed, a rim left);
* :func:`add_flange`, :func:`add_support` (legs or a frame of legs and beams), :func:`add_handles`
  — closed external solids;
* :func:`add_inside` — internal baffles or ribs: closed solids inside the cavity, every face
  ``internal``.

Each piece is a closed, consistently oriented surface with normals out of the metal (the shell's
inner faces point into the cavity), so the mesh is watertight per edge (pieces may intersect: a
leg enters the bottom plate). Frame: origin at the centre of the top opening, +Z up, the floor
at ``z = -height`` (ARCHITECTURE §5). The bin's largest dimension lies in 0.4–1.5 m.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import ConfigError
from cellctl.geometry.bin_meshes import _Builder
from cellctl.surface import EXTERNAL, INTERNAL

__all__ = ["FAMILIES", "OPTIONS", "FamilyParams", "build_family_mesh", "draw_params", "write_family_mesh"]

FAMILY_STREAM = 35
"""First word of every family seed sequence (the issue's number): a family's draws never share a
stream with another seeded part of the project."""

OPTIONS: dict[str, tuple[str, ...]] = {
    "body": ("cylinder", "polygon", "rect"),
    "bottom": ("flat", "dished", "hopper"),
    "opening": ("round", "square", "open"),
    "opening_width": ("narrow", "wide"),
    "opening_place": ("centred", "off_centre"),
    "flange": ("none", "flange"),
    "support": ("none", "legs", "frame"),
    "handles": ("none", "handles"),
    "inside": ("none", "baffle", "ribs"),
}
"""Every option of the family and its choices (a test checks each is drawn by some seed)."""

FAMILIES: dict[str, dict[str, tuple[str, ...]]] = {
    "mixed": OPTIONS,
    "hopper": {
        **OPTIONS,
        "bottom": ("hopper",),
        "opening": ("round", "square"),
        "opening_width": ("narrow",),
        "support": ("legs", "frame"),
    },
    "open": {
        **OPTIONS,
        "bottom": ("flat", "dished"),
        "opening": ("open", "round", "square"),
        "opening_width": ("wide",),
    },
}
"""Family name → the choices it draws from: ``mixed`` draws every option; ``hopper`` narrow-opening
hoppers (the cavities that are hard to see into); ``open`` wide openings and flat/dished bottoms."""

SIZE_RANGE_M = (0.4, 1.5)
"""The bin's largest dimension (width, depth or floor-to-top height)."""
THICKNESS_M = 0.004
ROW_SPACING_M = 0.08
RIM_CLEAR_M = 0.03
HANDLE_BAR_M = 0.024
"""A handle's bar and standoffs: square section."""
HANDLE_REACH_M = 0.072
"""How far a handle stands out of the wall (to its bar's outer face)."""
"""Metal kept between an opening and the inner wall."""


@dataclass(frozen=True)
class FamilyParams:
    """One drawn bin (metres, degrees). ``choices`` holds the option names of :data:`OPTIONS`."""

    family: str
    seed: int
    choices: dict[str, str]
    sides: int
    half_x: float
    half_y: float
    wall_height: float
    bottom_depth: float
    outlet_scale: float
    opening_half: float
    opening_offset: tuple[float, float]
    rim: float
    flange_width: float
    support_height: float
    n_legs: int
    leg_size: float
    inside_count: int
    inside_depth: float

    @property
    def height(self) -> float:
        """Floor to top (m)."""
        return self.wall_height + self.bottom_depth + self.support_height

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "height_m": self.height}


def _pick(rng: np.random.Generator, choices: tuple[str, ...]) -> str:
    return str(choices[int(rng.integers(len(choices)))])


def draw_params(family: str, seed: int) -> FamilyParams:
    """The parameters of bin ``seed`` of ``family`` (deterministic per pair).

    Raises:
        ConfigError: an unknown family or a negative seed.
    """
    if family not in FAMILIES:
        raise ConfigError(f"shape family {family!r} is unknown; expected one of {sorted(FAMILIES)}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"shape family seed {seed!r} must be a non-negative integer")
    rng = np.random.default_rng([FAMILY_STREAM, sorted(FAMILIES).index(family), seed])
    allowed = FAMILIES[family]
    ch = {k: _pick(rng, allowed[k]) for k in OPTIONS}
    if ch["bottom"] == "hopper" and ch["support"] == "none":
        ch["support"] = "legs"  # a hopper stands on something
    if ch["opening"] == "open":
        ch["opening_width"], ch["opening_place"] = "wide", "centred"  # the whole top is the opening
    size = float(rng.uniform(*SIZE_RANGE_M))
    aspect = float(rng.uniform(0.6, 1.6))  # floor-to-top height / width
    height, width = (size, size / aspect) if aspect >= 1 else (size * aspect, size)
    width = max(width, 0.4)  # room for an opening and a camera's view into it
    sides = {"cylinder": 0, "polygon": int(rng.integers(5, 9)), "rect": 4}[ch["body"]]
    depth_ratio = float(rng.uniform(0.6, 1.0)) if ch["body"] == "rect" else 1.0
    flange = float(rng.uniform(0.03, 0.06)) if ch["flange"] == "flange" else 0.0
    # the drawn width is the bin's whole extent: the flange and the handles (on ±x) stand inside it
    half_x = width / 2 - max(flange, HANDLE_REACH_M if ch["handles"] == "handles" else 0.0)
    half_y = half_x * depth_ratio
    support = {"none": 0.0, "legs": rng.uniform(0.12, 0.25), "frame": rng.uniform(0.15, 0.3)}[ch["support"]]
    support = float(support) * height
    below = {"flat": 0.0, "dished": rng.uniform(0.05, 0.12) * width, "hopper": rng.uniform(0.2, 0.4) * height}
    bottom = float(below[ch["bottom"]])
    wall = height - support - bottom
    if wall < 0.15:  # a short bin: keep a straight wall, shrink what lies below it
        scale = (height - 0.15) / max(support + bottom, 1e-9)
        support, bottom, wall = support * scale, bottom * scale, 0.15
    inradius = _inradius(ch["body"], sides, half_x, half_y) - THICKNESS_M
    frac = rng.uniform(0.3, 0.5) if ch["opening_width"] == "narrow" else rng.uniform(0.6, 0.85)
    corner = math.sqrt(2.0) if ch["opening"] == "square" else 1.0  # a square's corner reaches √2·half
    half_open = float(frac) * (inradius - RIM_CLEAR_M) / corner
    offset = (0.0, 0.0)
    if ch["opening_place"] == "off_centre":
        room = inradius - RIM_CLEAR_M - half_open * corner
        a = float(rng.uniform(0, 2 * math.pi))
        r = float(rng.uniform(0.5, 0.9)) * room
        offset = (r * math.cos(a), r * math.sin(a))
    return FamilyParams(
        family=family,
        seed=seed,
        choices=ch,
        sides=sides,
        half_x=half_x,
        half_y=half_y,
        wall_height=wall,
        bottom_depth=bottom,
        outlet_scale=float(rng.uniform(0.15, 0.3)) if ch["bottom"] == "hopper" else 1.0,
        opening_half=half_open,
        opening_offset=offset,
        rim=float(rng.uniform(0.02, 0.05)),
        flange_width=flange,
        support_height=support,
        n_legs=4 if ch["body"] == "rect" else int(rng.integers(3, 5)),
        leg_size=float(rng.uniform(0.04, 0.07)),
        inside_count={"none": 0, "baffle": int(rng.integers(1, 3)), "ribs": int(rng.integers(3, 7))}[ch["inside"]],
        inside_depth=float(rng.uniform(0.25, 0.45)) if ch["inside"] == "baffle" else float(rng.uniform(0.02, 0.04)),
    )


def _inradius(body: str, sides: int, half_x: float, half_y: float) -> float:
    if body == "cylinder":
        return half_x
    if body == "polygon":
        return half_x * math.cos(math.pi / sides)
    return min(half_x, half_y)


# --- stages ------------------------------------------------------------------------------------


def outline(p: FamilyParams) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Perimeter points (N, 2) CCW at full section scale, and per point the offset direction whose
    multiple by ``t`` moves the outline ``t`` inwards (corners: the exact miter, not a unit vector)."""
    if p.sides == 0:
        a = np.linspace(0, 2 * np.pi, 64, endpoint=False)
        u = np.stack([np.cos(a), np.sin(a)], 1)
        return p.half_x * u, u
    if p.sides == 4:
        corners = np.array([[p.half_x, -p.half_y], [p.half_x, p.half_y], [-p.half_x, p.half_y], [-p.half_x, -p.half_y]])
    else:  # a flat side faces -y (the side a board would be on)
        a = -np.pi / 2 + np.pi / p.sides + 2 * np.pi * np.arange(p.sides) / p.sides
        corners = p.half_x * np.stack([np.cos(a), np.sin(a)], 1)
    k = len(corners)
    edge = np.roll(corners, -1, axis=0) - corners
    n_edge = np.stack([edge[:, 1], -edge[:, 0]], 1) / np.linalg.norm(edge, axis=1)[:, None]
    perim = float(np.linalg.norm(edge, axis=1).sum())
    # a corner's miter (n1 + n2) / (1 + n1·n2) offsets both its edges by exactly one unit; along an
    # edge the offset direction is interpolated between its corners' miters, so an offset outline
    # is the offset polygon sampled at the same fractions (no point passes its neighbour near a corner)
    miter = (np.roll(n_edge, 1, axis=0) + n_edge) / (1.0 + np.einsum("ij,ij->i", np.roll(n_edge, 1, axis=0), n_edge))[
        :, None
    ]
    pts, nrm = [], []
    for i in range(k):
        m = max(3, int(round(64 * np.linalg.norm(edge[i]) / perim)))
        for j in range(m):
            f = j / m
            pts.append(corners[i] + edge[i] * f)
            nrm.append((1 - f) * miter[i] + f * miter[(i + 1) % k])
    return np.array(pts), np.array(nrm)


def body_sections(p: FamilyParams) -> list[tuple[float, float]]:
    """``(z, scale)`` of the outline from the top (z = 0) down to the bottom plate."""
    secs = [(0.0, 1.0), (-p.wall_height, 1.0)]
    if p.choices["bottom"] == "hopper":
        secs.append((-p.wall_height - p.bottom_depth, p.outlet_scale))
    elif p.choices["bottom"] == "dished":  # an elliptic dish down to a small flat centre
        rings = (0.9, 0.7, 0.45, 0.2)
        for s in rings:  # the last ring (the flat centre) at the full depth: the floor is at -height
            secs.append((-p.wall_height - p.bottom_depth * math.sqrt((1 - s * s) / (1 - rings[-1] ** 2)), s))
    return secs


def _opening(p: FamilyParams, P: NDArray[np.float64], Nrm: NDArray[np.float64]) -> NDArray[np.float64]:
    """The opening's rim points, one per outline point (the top plate joins them one to one)."""
    if p.choices["opening"] == "open":
        return P - p.rim * Nrm
    c = np.asarray(p.opening_offset)
    d = P - c
    ang = np.arctan2(d[:, 1], d[:, 0])
    u = np.stack([np.cos(ang), np.sin(ang)], 1)
    if p.choices["opening"] == "square":
        return c + u * (p.opening_half / np.maximum(np.abs(u[:, 0]), np.abs(u[:, 1])))[:, None]
    return c + p.opening_half * u


def _rows(P: NDArray[np.float64], Nrm: NDArray[np.float64], secs: list[tuple[float, float]], t: float) -> NDArray:
    """Wall rings (R, N, 3) along the sections, ``t`` inside the outline (inner rings end ``t`` in)."""
    rows = []
    for k in range(len(secs) - 1):
        (z0, s0), (z1, s1) = secs[k], secs[k + 1]
        m = max(1, int(math.ceil(abs(z0 - z1) / ROW_SPACING_M)))
        for i in range(m + (1 if k == len(secs) - 2 else 0)):
            f = i / m
            z, s = z0 + f * (z1 - z0), s0 + f * (s1 - s0)
            if t > 0 and k == 0 and i == 0:
                z = -t  # under the top plate
            elif t > 0 and k == len(secs) - 2 and i == m:
                z = z1 + t  # over the bottom plate
            rows.append(np.column_stack([P * s - t * Nrm, np.full(len(P), z)]))
    return np.array(rows)


def add_shell(b: _Builder, p: FamilyParams) -> None:
    """The thin-walled body, its bottom, the top plate and the opening's rim (see the module doc)."""
    P, Nrm = outline(p)
    t = THICKNESS_M
    secs = body_sections(p)
    up = lambda c: np.tile([0.0, 0.0, 1.0], (len(c), 1))  # noqa: E731
    down = lambda c: np.tile([0.0, 0.0, -1.0], (len(c), 1))  # noqa: E731
    # the body (prism, hopper or dish) is convex: away from a point on its axis is outwards everywhere
    centre = np.array([0.0, 0.0, 0.5 * secs[-1][0]])
    out = lambda c: c - centre  # noqa: E731
    b.grid(_rows(P, Nrm, secs, 0.0), EXTERNAL, out)
    b.grid(_rows(P, Nrm, secs, t), INTERNAL, lambda c: -out(c))
    H = _opening(p, P, Nrm)
    hole_c = np.r_[np.asarray(p.opening_offset) if p.choices["opening"] != "open" else (0.0, 0.0), 0.0]
    rings = 3
    for z, off, tag, ref in ((0.0, 0.0, EXTERNAL, up), (-t, t, INTERNAL, down)):
        rows = [
            np.column_stack([(P - off * Nrm) + i / rings * (H - (P - off * Nrm)), np.full(len(P), z)])
            for i in range(rings + 1)
        ]
        b.grid(np.array(rows), tag, ref)
    rim = np.array([np.column_stack([H, np.zeros(len(P))]), np.column_stack([H, np.full(len(P), -t)])])
    b.grid(rim, EXTERNAL, lambda c: hole_c - np.column_stack([c[:, :2], np.zeros(len(c))]))
    zb, sb = secs[-1]
    b.fan(np.column_stack([P * sb, np.full(len(P), zb)]), np.array([0.0, 0.0, zb]), EXTERNAL, down)
    b.fan(np.column_stack([P * sb - t * Nrm, np.full(len(P), zb + t)]), np.array([0.0, 0.0, zb + t]), INTERNAL, up)


def _box(b: _Builder, centre: NDArray, axes: NDArray, half: NDArray, tag: int) -> None:
    """A closed box: ``axes`` (3, 3) rows are its unit directions, ``half`` its half-sizes along them."""
    signs = np.array([[sx, sy, sz] for sz in (-1, 1) for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))], float)
    corners = centre + (signs * half) @ axes
    quads = [(0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7), (4, 5, 6, 7), (0, 3, 2, 1)]
    F = np.array([tri for a, b_, c, e in quads for tri in ((a, b_, c), (a, c, e))], dtype=np.int64)
    b.mesh(corners, F, tag, lambda c: c - centre)  # convex: outward = away from the centre


def _beam(b: _Builder, p0: NDArray, p1: NDArray, half_w: float, tag: int) -> None:
    """A square beam from ``p0`` to ``p1`` (3-vectors)."""
    d = np.asarray(p1, float) - np.asarray(p0, float)
    x = d / np.linalg.norm(d)
    helper = np.array([0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(helper, x)
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    _box(
        b,
        (np.asarray(p0) + np.asarray(p1)) / 2,
        np.array([x, y, z]),
        np.array([np.linalg.norm(d) / 2, half_w, half_w]),
        tag,
    )


def _wall_hit(P: NDArray[np.float64], u: NDArray[np.float64], origin: NDArray | None = None) -> tuple[float, NDArray]:
    """Distance from ``origin`` (default the body's axis) to the convex outline ``P`` along the
    horizontal unit ``u``, and the outward unit normal of the edge it hits."""
    o = np.zeros(2) if origin is None else np.asarray(origin, float)
    A = P - o
    E = np.roll(P, -1, axis=0) - P
    den = u[0] * -E[:, 1] + u[1] * E[:, 0]
    ok = np.abs(den) > 1e-12
    s = np.where(ok, (A[:, 0] * -E[:, 1] + A[:, 1] * E[:, 0]) / np.where(ok, den, 1.0), -1.0)
    w = np.where(ok, (u[0] * A[:, 1] - u[1] * A[:, 0]) / np.where(ok, den, 1.0), -1.0)
    hit = ok & (s > 0) & (w >= -1e-9) & (w <= 1 + 1e-9)
    i = int(np.flatnonzero(hit)[np.argmax(s[hit])])
    n = np.array([E[i, 1], -E[i, 0]]) / np.linalg.norm(E[i])
    return float(s[i]), n


def add_flange(b: _Builder, p: FamilyParams) -> None:
    """A flat ring around the top: a closed slab from inside the wall's metal out by ``flange_width``,
    just under the top plate (no coplanar faces)."""
    if p.flange_width <= 0:
        return
    P, Nrm = outline(p)
    ft, z0 = 0.012, -0.003
    inner, outer = P - 0.5 * THICKNESS_M * Nrm, P + p.flange_width * Nrm
    ring = lambda xy, z: np.column_stack([xy, np.full(len(xy), z)])  # noqa: E731
    rad = lambda c: np.column_stack([c[:, :2], np.zeros(len(c))])  # noqa: E731
    vert = lambda sz: lambda c: np.tile([0.0, 0.0, sz], (len(c), 1))  # noqa: E731
    b.grid(np.array([ring(outer, z0), ring(outer, z0 - ft)]), EXTERNAL, rad)
    b.grid(np.array([ring(inner, z0), ring(inner, z0 - ft)]), EXTERNAL, lambda c: -rad(c))
    b.grid(np.array([ring(inner, z0), ring(outer, z0)]), EXTERNAL, vert(1.0))
    b.grid(np.array([ring(inner, z0 - ft), ring(outer, z0 - ft)]), EXTERNAL, vert(-1.0))


def add_support(b: _Builder, p: FamilyParams) -> None:
    """Legs (square, floor to a little up the straight wall, welded to it from outside) or a frame
    (the legs joined by beams a third of the way up)."""
    if p.choices["support"] == "none":
        return
    P, _ = outline(p)
    floor = -p.height
    top = -p.wall_height + min(0.15, 0.5 * p.wall_height)
    half = p.leg_size / 2
    feet = []
    for a in np.pi / 4 + 2 * np.pi * np.arange(p.n_legs) / p.n_legs:
        dist, n = _wall_hit(P, np.array([math.cos(a), math.sin(a)]))
        w = dist * np.array([math.cos(a), math.sin(a)])
        xy = w + n * (half - THICKNESS_M / 2)  # the leg's inner face in the wall's metal
        feet.append(xy)
        axes = np.array([[n[0], n[1], 0.0], [-n[1], n[0], 0.0], [0.0, 0.0, 1.0]])
        _box(b, np.array([xy[0], xy[1], (floor + top) / 2]), axes, np.array([half, half, (top - floor) / 2]), EXTERNAL)
    if p.choices["support"] == "frame":
        z = floor + 0.35 * (min(top, -p.wall_height - p.bottom_depth) - floor)
        for i in range(len(feet)):
            _beam(b, np.r_[feet[i], z], np.r_[feet[(i + 1) % len(feet)], z], 0.4 * half, EXTERNAL)


def add_handles(b: _Builder, p: FamilyParams) -> None:
    """Two bar handles on opposite sides (±x), each on two standoffs from the straight wall."""
    if p.choices["handles"] == "none":
        return
    P, _ = outline(p)
    z = -min(0.12, 0.3 * p.wall_height)
    hw = HANDLE_BAR_M / 2
    span = min(0.1, 0.5 * p.half_y)
    for sgn in (1.0, -1.0):
        ux = np.array([sgn, 0.0])
        x_at = {y: _wall_hit(P, ux, np.array([0.0, y]))[0] for y in (-span - hw, -span + hw, span - hw, span + hw)}
        x_bar = max(x_at.values()) + HANDLE_REACH_M - hw
        for y in (-span, span):
            # from the wall's metal where it stands furthest out: never into the cavity
            x0 = max(x_at[y - hw], x_at[y + hw]) - THICKNESS_M / 2
            _beam(b, np.array([sgn * x0, y, z]), np.array([sgn * x_bar, y, z]), hw, EXTERNAL)
        _beam(b, np.array([sgn * x_bar, -span - 2 * hw, z]), np.array([sgn * x_bar, span + 2 * hw, z]), hw, EXTERNAL)


def add_inside(b: _Builder, p: FamilyParams) -> None:
    """Baffles (plates from the wall towards the axis) or ribs (narrow strips on the inner wall),
    over the straight wall below the top plate, square to the wall; every face internal."""
    if p.inside_count == 0:
        return
    P, _ = outline(p)
    z0, z1 = -0.15 * p.wall_height - 0.02, -0.9 * p.wall_height
    half_t = 0.005 if p.choices["inside"] == "baffle" else 0.008
    for k in range(p.inside_count):
        a = 2 * np.pi * (k + 0.5) / p.inside_count + 0.3
        u = np.array([math.cos(a), math.sin(a)])
        dist, n = _wall_hit(P, u)
        depth = p.inside_depth * dist if p.choices["inside"] == "baffle" else p.inside_depth
        outer_end = dist * u - n * (THICKNESS_M / 2)  # in the wall's metal
        inner_end = dist * u - n * (THICKNESS_M + depth)
        centre = np.r_[(outer_end + inner_end) / 2, (z0 + z1) / 2]
        axes = np.array([[n[0], n[1], 0.0], [-n[1], n[0], 0.0], [0.0, 0.0, 1.0]])
        half = np.array([(THICKNESS_M / 2 + depth) / 2, half_t, (z0 - z1) / 2])
        _box(b, centre, axes, half, INTERNAL)


def build_family_mesh(p: FamilyParams) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.uint8]]:
    """Vertices (V, 3), faces (F, 3) and surface tags (F,) of one drawn bin, in the bin frame
    (the body is shifted so the origin is the opening's centre)."""
    b = _Builder()
    for stage in (add_shell, add_flange, add_support, add_handles, add_inside):
        stage(b, p)
    V, F, S = b.result()
    if p.choices["opening"] != "open":
        V = V - np.r_[p.opening_offset, 0.0]
    return V, F, S


def family_mesh(family: str, seed: int) -> Any:
    """The :class:`~cellctl.geometry.catalog.BinMesh` of bin ``seed`` of ``family``, named
    ``<family>_<seed>``, its surface tags kept."""
    from cellctl.planning.mesh import mesh_from_arrays

    p = draw_params(family, seed)
    V, F, S = build_family_mesh(p)
    return mesh_from_arrays(V, F, name=f"{family}_{seed}", internal=S == INTERNAL)


def write_family_mesh(family: str, seed: int, out: Path) -> dict[str, Any]:
    """Write bin ``seed`` of ``family`` to ``out`` (any trimesh format; PLY keeps its tags inline),
    its tags to ``<out>.surface.npy`` and its parameters to ``<out>.json``; return the parameters.

    Raises:
        ConfigError: an unknown family, a bad seed or an unwritable path.
    """
    import trimesh

    from cellctl.geometry.catalog import write_ply

    p = draw_params(family, seed)
    V, F, S = build_family_mesh(p)
    out = Path(out)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        if out.suffix.lower() == ".ply":
            write_ply(out, V, F, S)
        else:
            trimesh.Trimesh(V, F, process=False).export(out)
        np.save(out.with_suffix(out.suffix + ".surface.npy"), S.astype(np.uint8))
        info = {
            **p.to_json(),
            "mesh": str(out),
            "extent_m": (V.max(axis=0) - V.min(axis=0)).tolist(),  # x, y, z; the largest in SIZE_RANGE_M
            "faces": int(len(F)),
            "internal_faces": int((S == INTERNAL).sum()),
        }
        out.with_suffix(out.suffix + ".json").write_text(json.dumps(info, indent=2) + "\n")
    except OSError as err:
        raise ConfigError(f"cannot write the family mesh to {str(out)!r}: {err}") from err
    return info
