"""Draw a cycle's dirt map: the bin mesh coloured by faces seen dirty, seen clean, never seen."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cellctl.errors import RecordingError

__all__ = ["COLOURS", "draw_dirt_map", "face_states"]

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


def draw_dirt_map(
    mesh: Any, dirt_map: dict[str, Any], out: Path, title: str = "", camera_positions: np.ndarray | None = None
) -> Path:
    """Write a PNG with two views of the bin (outside and from above) coloured by the dirt map.

    Args:
        mesh: a :class:`cellctl.geometry.catalog.BinMesh` (bin frame, metres).
        dirt_map: ``{"seen_dirty": [...], "seen_clean": [...]}`` face ids.
        camera_positions: optional (N, 3) viewpoint positions in the bin frame, drawn as dots.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    states = face_states(mesh.n_faces, dirt_map)
    colours = np.array([COLOURS["unseen"], COLOURS["clean"], COLOURS["dirty"]])[states]
    tris = mesh.vertices[mesh.faces]
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
    fig.suptitle(f"{title}  dirty faces {n[2]}, clean {n[1]}, unseen {n[0]} (red dirty, green clean, grey unseen)")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, bbox_inches="tight")
    plt.close(fig)
    return out
