"""Draw a cycle's dirt map: the bin mesh coloured by each face's dirt probability (or state).

A dirt map with ``face_p`` (per-face fused probabilities, :mod:`cellctl.classify.heatmap`) is
drawn on a green → yellow → red scale, unseen faces grey; an older map (lists of faces seen
dirty / seen clean only) in the three state colours.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cellctl.errors import RecordingError

__all__ = ["COLOURS", "draw_dirt_map", "face_colours", "face_states", "probability_colours"]

COLOURS = {"dirty": (0.85, 0.15, 0.1, 1.0), "clean": (0.2, 0.7, 0.3, 1.0), "unseen": (0.8, 0.8, 0.82, 0.35)}


def face_states(n_faces: int, dirt_map: dict[str, Any]) -> np.ndarray:
    """Per-face state codes: 0 unseen, 1 seen clean, 2 seen dirty."""
    s = np.zeros(n_faces, np.uint8)
    for key, code in (("seen_clean", 1), ("seen_dirty", 2)):
        ids = np.asarray(dirt_map.get(key, []), dtype=np.int64)
        if ids.size and (ids.min() < 0 or ids.max() >= n_faces):
            raise RecordingError(f"dirt map face id {int(ids.max())} is out of range for a mesh of {n_faces} faces")
        s[ids] = code
    return s


def probability_colours(p: np.ndarray) -> np.ndarray:
    """RGBA ``(F, 4)`` for probabilities ``(F,)``: green 0 → yellow 0.5 → red 1; NaN = unseen grey."""
    p = np.asarray(p, np.float64)
    q = np.clip(np.nan_to_num(p, nan=0.0), 0, 1)[:, None]
    green, yellow, red = (np.array(COLOURS["clean"]), np.array((0.95, 0.8, 0.1, 1.0)), np.array(COLOURS["dirty"]))
    rgba = np.where(q < 0.5, green + (yellow - green) * (q / 0.5), yellow + (red - yellow) * ((q - 0.5) / 0.5))
    rgba[np.isnan(p)] = COLOURS["unseen"]
    return rgba


def face_colours(n_faces: int, dirt_map: dict[str, Any]) -> np.ndarray:
    """RGBA per face: by probability when the map has ``face_p``, else by state."""
    from cellctl.classify.heatmap import face_probabilities
    from cellctl.errors import ClassifierError

    try:
        p = face_probabilities(dirt_map, n_faces)
    except ClassifierError as err:
        raise RecordingError(str(err)) from err
    if p is not None:
        return probability_colours(p)
    return np.array([COLOURS["unseen"], COLOURS["clean"], COLOURS["dirty"]])[face_states(n_faces, dirt_map)]


def draw_dirt_map(
    mesh: Any,
    dirt_map: dict[str, Any],
    out: Path,
    title: str = "",
    camera_positions: np.ndarray | None = None,
    surface: str | None = None,
) -> Path:
    """Write a PNG with two views of the bin (outside and from above) coloured by the dirt map.

    Args:
        mesh: a :class:`cellctl.geometry.catalog.BinMesh` (bin frame, metres).
        dirt_map: ``{"seen_dirty": [...], "seen_clean": [...]}`` face ids.
        camera_positions: optional (N, 3) viewpoint positions in the bin frame, drawn as dots.
        surface: draw only this surface's faces (``internal``: the cavity, no outer wall in front of it);
            the counts are that surface's.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    states = face_states(mesh.n_faces, dirt_map)
    colours = face_colours(mesh.n_faces, dirt_map)
    graded = "face_p" in dirt_map
    tris = mesh.vertices[mesh.faces]
    if surface is not None:
        from cellctl.surface import FACE_TAG

        keep = np.asarray(mesh.surface) == FACE_TAG[surface]  # type: ignore[index]
        states, colours, tris = states[keep], colours[keep], tris[keep]
        title = f"{title} — {surface} surface".strip(" —")
    fig = plt.figure(figsize=(12, 6), dpi=110)
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    for i, (elev, azim, name) in enumerate(((18, -60, "outside"), (80, -90, "from above"))):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(tris, facecolors=colours, edgecolors=(0, 0, 0, 0.05), linewidths=0.1))
        if camera_positions is not None and len(camera_positions):
            c = np.asarray(camera_positions)
            ax.scatter(c[:, 0], c[:, 1], c[:, 2], c="tab:blue", s=12, depthshade=False)
            lo, hi = np.minimum(lo, c.min(0)), np.maximum(hi, c.max(0))
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_zlim(lo[2], hi[2])
        ax.set_box_aspect(hi - lo)
        ax.view_init(elev, azim)
        ax.set_title(name)
        ax.set_axis_off()
    n = np.bincount(states, minlength=3)
    legend = (
        "colour = fused dirt probability per face: green 0, yellow 0.5, red 1; grey unseen"
        if graded
        else "red dirty, green clean, grey unseen"
    )
    area = f", dirty area {dirt_map['dirty_area_m2'] * 1e4:.1f} cm²" if graded and "dirty_area_m2" in dirt_map else ""
    fig.suptitle(f"{title}  dirty faces {n[2]}{area}, clean {n[1]}, unseen {n[0]}\n({legend})")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, bbox_inches="tight")
    plt.close(fig)
    return out
