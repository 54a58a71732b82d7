"""Pictures of a wash round: the wash path on the bin mesh (the dirt maps are drawn by
:func:`cellctl.recording.dirt_map.draw_dirt_map`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cellctl.geometry.catalog import BinMesh
from cellctl.washing.plan import WashPlan

__all__ = ["draw_wash_path"]

_GREY = (0.82, 0.82, 0.84, 0.25)
_DIRTY = (0.85, 0.15, 0.1, 1.0)
_TARGET = (0.98, 0.62, 0.2, 0.9)
_WASHED = (0.45, 0.7, 0.95, 0.6)
_UNWASHABLE = (0.45, 0.0, 0.45, 1.0)


def draw_wash_path(mesh: BinMesh, plan: WashPlan, spots: list[Any], out: Path, title: str = "") -> Path:
    """Two views (outside, from above) of the bin: dirty faces red, the margin orange, faces
    the jet sprays blue, unwashable purple; each sweep's spot path as a line (dark blue); the
    stations used named by their direction in the title.

    Args:
        spots: the plan's passes (:func:`cellctl.washing.spots.plan_spots`, or the twin's
            :class:`cellctl.sim.ground_truth.SprayPass`: their ``spots`` and ``axes``).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    col = np.tile(np.array(_GREY), (mesh.n_faces, 1))
    col[plan.washed] = _WASHED
    col[plan.targets & ~plan.dirty] = _TARGET
    col[plan.dirty] = _DIRTY
    for u in plan.unwashable:
        col[u.faces] = _UNWASHABLE
    tris = mesh.vertices[mesh.faces]
    # each sweep once (its passes go back and forth), lifted 1 cm towards the nozzle
    segs = [np.asarray(sp.spots) - 0.01 * np.asarray(sp.axes) for sp in spots[::2] if len(sp.spots) > 1]
    dots = np.array([sp.spots[0] for sp in spots[::2] if len(sp.spots) == 1]).reshape(-1, 3)
    used = sorted({s.station for s in plan.sweeps})
    heads = [
        f"{np.degrees(np.arctan2(plan.stations[k][1, 3], plan.stations[k][0, 3])):+.0f}°" for k in used
    ]  # direction of each station used from the bin's centre
    fig = plt.figure(figsize=(12, 6), dpi=110)
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    lo_all, hi_all = lo - 0.02, hi + 0.02  # the bin fills the view; the stations are named in the title
    for i, (elev, azim, name) in enumerate(((18, -60, "outside"), (80, -90, "from above"))):
        ax = fig.add_subplot(1, 2, i + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(tris, facecolors=col, edgecolors=(0, 0, 0, 0.04), linewidths=0.1))
        if segs:  # lifted a little off the surface along the jet so the faces do not hide them
            ax.add_collection3d(Line3DCollection(segs, colors="navy", linewidths=1.6, zorder=5))
        if len(dots):
            ax.scatter(dots[:, 0], dots[:, 1], dots[:, 2], c="navy", s=8, depthshade=False)
        ax.set_xlim(lo_all[0], hi_all[0])
        ax.set_ylim(lo_all[1], hi_all[1])
        ax.set_zlim(lo_all[2], hi_all[2])
        ax.set_box_aspect(hi_all - lo_all)
        ax.view_init(elev, azim)
        ax.set_title(name)
        ax.set_axis_off()
    a = mesh.areas
    fig.suptitle(
        f"{title}  {len(plan.sweeps)} sweeps, {sum(s.passes for s in plan.sweeps)} passes from {len(used)} station(s); "
        f"dirty {a[plan.dirty].sum() * 1e4:.0f} cm², washed {a[plan.washed].sum() * 1e4:.0f} cm², "
        f"unwashable {sum(u.area_m2 for u in plan.unwashable) * 1e4:.0f} cm²\n"
        f"stations at {', '.join(heads)} around the bin; red dirty, orange margin, blue sprayed, purple unwashable, "
        "lines: the jet's spot paths"
    )
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, bbox_inches="tight")
    plt.close(fig)
    return out
