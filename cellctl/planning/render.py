"""PNG of a plan: mesh coloured by how many selected viewpoints see each face, viewpoints, tour."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cellctl.geometry.catalog import BinMesh
from cellctl.planning.plan import Plan

__all__ = ["equal_axes", "render_plan"]


def equal_axes(ax, points: np.ndarray) -> None:  # a matplotlib 3D axes
    """One scale on x, y, z around ``points`` (N, 3), metres labelled: shapes are not distorted."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    c, r = (lo + hi) / 2, (hi - lo).max() / 2
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")


def render_plan(plan: Plan, mesh: BinMesh, path: str | Path) -> Path:
    """Draw the plan like paper Figs. 10–11 and save it as a PNG (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    count = np.zeros(len(mesh.faces), dtype=int)
    for vp in plan.viewpoints:
        count[vp.faces] += 1
    fig = plt.figure(figsize=(9, 7), dpi=110)
    ax = fig.add_subplot(111, projection="3d")
    ax.computed_zorder = False  # draw viewpoints and tour on top of the mesh (mpl cannot depth-sort them)
    cmap = plt.get_cmap("viridis")
    vmax = max(1, int(count.max()))
    colors = np.where((count > 0)[:, None], cmap(count / vmax), np.array([[0.75, 0.75, 0.75, 0.9]]))
    # the other surface is drawn faint, so an internal plan can be seen through the shell
    other = ~mesh.surface_mask(plan.surface)
    colors[other] = (0.85, 0.85, 0.85, 0.06 if plan.surface == "internal" else 0.5)
    poly = Poly3DCollection(mesh.vertices[mesh.faces], facecolors=colors, edgecolors="none")
    ax.add_collection3d(poly)
    T = np.array([vp.T_bin_cam for vp in plan.viewpoints]).reshape(-1, 4, 4)
    if len(T):
        p, z = T[:, :3, 3], T[:, :3, 2]
        ax.quiver(p[:, 0], p[:, 1], p[:, 2], z[:, 0], z[:, 1], z[:, 2], length=0.12, color="magenta", zorder=10)
        ax.plot(p[:, 0], p[:, 1], p[:, 2], "-o", color="red", ms=3, lw=1.2, label="tour", zorder=11)
        ax.text(*p[0], "1", color="red", zorder=12)
    base = plan.base.T_bin_base[:3, 3]
    ax.scatter(*base, color="black", s=40, marker="s", label="robot base", zorder=12)
    equal_axes(ax, np.vstack([mesh.vertices, base[None], T[:, :3, 3] if len(T) else mesh.vertices[:1]]))
    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(1, vmax))
    fig.colorbar(sm, ax=ax, shrink=0.6, label="selected viewpoints seeing the face")
    cnt = plan.counts
    ax.set_title(
        f"{plan.bin_type} {plan.surface}: {len(plan.viewpoints)} viewpoints "
        f"(GA {cnt.greedy}, reachable {cnt.reachable}), coverage {100 * plan.coverage:.1f} %"
    )
    ax.legend(loc="upper left")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out
