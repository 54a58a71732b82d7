"""Simple watertight bin shapes for tests, demos and planning without a catalog mesh."""

from __future__ import annotations

import numpy as np

from cellctl.geometry.catalog import BinMesh
from cellctl.planning.mesh import mesh_from_arrays

__all__ = ["open_box_bin"]


def open_box_bin(
    size: tuple[float, float, float] = (0.6, 0.4, 0.35),
    wall: float = 0.02,
    max_edge: float = 0.05,
    z_floor_gap: float = 0.0,
) -> BinMesh:
    """A watertight open-top box with thick walls, in the bin frame (origin: top-opening centre).

    Internal faces (the cavity: inner walls and inner bottom) are tagged ``internal``; the
    outside and the top rim are external.

    Args:
        size: outer length (x), width (y), height (z), m.
        wall: wall and bottom thickness, m.
        max_edge: faces are subdivided until no edge is longer, m (sets the face count).
        z_floor_gap: height of the bin bottom above the floor, m (stored as nothing: the
            floor is the mesh's lowest point unless the caller says otherwise).
    """
    import trimesh

    L, W, H = size
    hx, hy = L / 2, W / 2
    ix, iy = hx - wall, hy - wall
    zb, zi = -H, -H + wall

    def quad(a, b, c, d):  # counter-clockwise seen from the side the normal points to
        return [[a, b, c], [a, c, d]]

    V = np.array(
        [
            [-hx, -hy, 0],
            [hx, -hy, 0],
            [hx, hy, 0],
            [-hx, hy, 0],  # 0-3 outer top
            [-hx, -hy, zb],
            [hx, -hy, zb],
            [hx, hy, zb],
            [-hx, hy, zb],  # 4-7 outer bottom
            [-ix, -iy, 0],
            [ix, -iy, 0],
            [ix, iy, 0],
            [-ix, iy, 0],  # 8-11 inner top
            [-ix, -iy, zi],
            [ix, -iy, zi],
            [ix, iy, zi],
            [-ix, iy, zi],  # 12-15 inner bottom
        ],
        dtype=np.float64,
    )
    ext: list[list[int]] = []
    ext += quad(4, 7, 6, 5)  # outer bottom, normal -z
    ext += quad(4, 5, 1, 0)  # -y side
    ext += quad(5, 6, 2, 1)  # +x side
    ext += quad(6, 7, 3, 2)  # +y side
    ext += quad(7, 4, 0, 3)  # -x side
    ext += quad(0, 1, 9, 8) + quad(1, 2, 10, 9) + quad(2, 3, 11, 10) + quad(3, 0, 8, 11)  # rim, +z
    inn: list[list[int]] = []
    inn += quad(12, 13, 14, 15)  # inner bottom, normal +z
    inn += quad(12, 8, 9, 13)  # inner -y wall, normal +y
    inn += quad(13, 9, 10, 14)  # inner +x wall, normal -x
    inn += quad(14, 10, 11, 15)  # inner +y wall, normal -y
    inn += quad(15, 11, 8, 12)  # inner -x wall, normal +x
    F = np.array(ext + inn, dtype=np.int64)
    tags = np.array([False] * len(ext) + [True] * len(inn))
    # subdivide, carrying each face's tag to its children
    Vs, Fs, idx = trimesh.remesh.subdivide_to_size(V, F, max_edge=max_edge, return_index=True)
    return mesh_from_arrays(Vs, Fs, name=f"open_box_{L:g}x{W:g}x{H:g}", internal=tags[idx], require_watertight=True)
