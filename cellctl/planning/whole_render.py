"""PNGs of a whole-bin plan, one per surface: faces by how many views see them, unseen faces in
red, the stations (mobile base footprint, arm base, rank) and each station's viewpoints."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cellctl.geometry.catalog import BinMesh
from cellctl.planning.whole import WholePlan

__all__ = ["render_whole"]

STATION_COLOURS = (
    "tab:blue",
    "tab:orange",
    "tab:green",
    "tab:purple",
    "tab:brown",
    "tab:pink",
    "tab:olive",
    "tab:cyan",
)
UNSEEN = (0.85, 0.15, 0.15, 0.95)


def _paths(path: str | Path, surfaces: list[str]) -> dict[str, Path]:
    p = Path(path)
    stem = p.with_suffix("")
    return {s: Path(f"{stem}_{s}.png") for s in surfaces}


def render_whole(plan: WholePlan, mesh: BinMesh, path: str | Path) -> list[Path]:
    """Draw ``<path stem>_<surface>.png`` per planned surface; returns the files written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from cellctl.geometry import robot_model as rm
    from cellctl.planning.render import equal_axes

    surfaces = [s for s, v in plan.surfaces.items() if v.reason is None]
    out: list[Path] = []
    for surf, png in _paths(path, surfaces).items():
        count = np.zeros(len(mesh.faces), dtype=int)
        for st in plan.stations:
            p = st.plans.get(surf)
            if p is None:
                continue
            for vp in p.viewpoints:
                count[vp.faces] += 1
        on = mesh.surface_mask(surf)
        if surf == "internal":  # the outer shell would hide it: drawn cut open instead
            out.append(_render_inside(plan, mesh, count, png))
            continue
        fig = plt.figure(figsize=(10, 8), dpi=110)
        ax = fig.add_subplot(111, projection="3d")
        ax.computed_zorder = False
        cmap = plt.get_cmap("viridis")
        vmax = max(1, int(count[on].max()) if on.any() else 1)
        colours = np.where((count > 0)[:, None], cmap(np.minimum(count, vmax) / vmax), np.array([UNSEEN]))
        colours[~on] = (0.8, 0.8, 0.8, 0.05 if surf == "internal" else 0.4)
        ax.add_collection3d(Poly3DCollection(mesh.vertices[mesh.faces], facecolors=colours, edgecolors="none"))
        pts = [mesh.vertices]
        centre, size = rm.MOBILE_BASE_BOX
        for st in plan.stations:
            colour = STATION_COLOURS[st.rank % len(STATION_COLOURS)]
            T = st.T_bin_base
            hx, hy = size[0] / 2, size[1] / 2
            sq = np.array(
                [
                    [centre[0] + sx * hx, centre[1] + sy * hy, 0, 1]
                    for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1), (-1, -1))
                ]
            )
            foot = (T @ sq.T)[:3].T
            # the footprint at the arm base's height, where the station's marker is (not at the floor)
            ax.plot(foot[:, 0], foot[:, 1], np.full(len(foot), T[2, 3]), "-", color=colour, lw=2, zorder=12)
            b = T[:3, 3]
            ax.scatter(*b, color=colour, s=60, marker="s", zorder=13)
            ax.text(b[0], b[1], b[2] + 0.08, f"S{st.rank + 1}", color=colour, fontsize=11, weight="bold", zorder=14)
            pts.append(foot)
            p = st.plans.get(surf)
            if p is None or not p.viewpoints:
                continue
            Tc = np.array([vp.T_bin_cam for vp in p.viewpoints])
            o, z = Tc[:, :3, 3], Tc[:, :3, 2]
            ax.quiver(o[:, 0], o[:, 1], o[:, 2], z[:, 0], z[:, 1], z[:, 2], length=0.1, color=colour, zorder=10)
            ax.plot(o[:, 0], o[:, 1], o[:, 2], "-", color=colour, lw=0.8, zorder=11)
            pts.append(o)
        equal_axes(ax, np.vstack(pts))
        ax.view_init(elev=35 if surf == "external" else 60, azim=-60)
        ax.set_title(_caption(plan, surf))
        out.append(_finish(fig, ax, cmap, vmax, png))
    return out


def _caption(plan: WholePlan, surf: str) -> str:
    s = plan.surfaces[surf]
    return (
        f"{plan.bin_type} {surf}, whole bin: {len(plan.stations)} stations, {s.viewpoints} viewpoints\n"
        f"area {100 * s.area_fraction:.1f} % of the surface, {100 * s.bound_fraction:.1f} % of the upper bound, "
        f"{100 * s.arm_bound_fraction:.1f} % of the arm-aware bound; modelled cycle {plan.cycle_time_s:.0f} s"
    )


def _finish(fig, axes, cmap, vmax: int, png: Path) -> Path:  # matplotlib objects
    """The colour bar of view counts, then the PNG."""
    import matplotlib.pyplot as plt

    sm = plt.cm.ScalarMappable(cmap=cmap, norm=plt.Normalize(1, vmax))
    fig.colorbar(sm, ax=axes, shrink=0.6, label="viewpoints seeing the face (red: unseen)")
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, bbox_inches="tight")
    plt.close(fig)
    return png


INSIDE_VIEWS = (
    ("from above, through the opening", 89.0, -90.0),
    ("cut open, far half from -y", 22.0, -90.0),
    ("cut open, far half from +y", 22.0, 90.0),
    ("cut open, far half from +x", 22.0, 0.0),
)
"""(title, elevation, azimuth) of the internal picture's panels (degrees, matplotlib's view)."""


def _render_inside(plan: WholePlan, mesh: BinMesh, count: np.ndarray, png: Path) -> Path:
    """The internal surface with the outer shell cut away: external faces left out, and in each
    view only the internal faces turned towards the eye (the near wall's inside faces away from
    it, so the far wall, the bottom and the baffles show). Unseen faces red. The side views
    look across the bin from three sides; the top view looks down through the opening."""
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from cellctl.planning.render import equal_axes

    on = mesh.surface_mask("internal")
    cmap = plt.get_cmap("viridis")
    vmax = max(1, int(count[on].max()) if on.any() else 1)
    colours = np.where((count > 0)[:, None], cmap(np.minimum(count, vmax) / vmax), np.array([UNSEEN]))
    tri = mesh.vertices[mesh.faces]
    cams = [vp.T_bin_cam for st in plan.stations if (p := st.plans.get("internal")) for vp in p.viewpoints]
    fig = plt.figure(figsize=(16, 13), dpi=90)
    for k, (title, elev, azim) in enumerate(INSIDE_VIEWS):
        ax = fig.add_subplot(2, 2, k + 1, projection="3d")
        e, a = np.radians(elev), np.radians(azim)
        eye = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        front = on & (mesh.normals @ eye > 0.02)
        ax.add_collection3d(Poly3DCollection(tri[front], facecolors=colours[front], edgecolors="none"))
        if cams and k == 0:  # where the internal views look from (camera positions, optical axes)
            Tc = np.array(cams)
            o, z = Tc[:, :3, 3], Tc[:, :3, 2]
            ax.quiver(o[:, 0], o[:, 1], o[:, 2], z[:, 0], z[:, 1], z[:, 2], length=0.08, color="k", lw=0.6)
        equal_axes(ax, tri[on].reshape(-1, 3))
        ax.view_init(elev=elev, azim=azim)
        ax.set_title(title)
    fig.suptitle(_caption(plan, "internal"))
    return _finish(fig, fig.axes, cmap, vmax, png)
