"""Where the jet's spot runs on the bin: the nozzle poses of a sweep ray-cast onto the mesh.

Sim-free (the supervisor draws the wash path with it; the twin turns the same spots into spray
passes over its powder, :mod:`cellctl.washing.twin`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.catalog import BinMesh
from cellctl.washing.nozzle import NozzleModel
from cellctl.washing.plan import WashPlan

__all__ = ["SpotPath", "plan_spots", "spray_path"]


@dataclass(frozen=True)
class SpotPath:
    """One pass of the jet: its spot centres on the surface (K, 3), jet directions (K, 3), spot radius (m)."""

    spots: NDArray[np.float64]
    axes: NDArray[np.float64]
    radius: float

    def reversed(self) -> SpotPath:
        return SpotPath(self.spots[::-1].copy(), self.axes[::-1].copy(), self.radius)


def spray_path(T_bin_noz: NDArray[np.float64], rays: Any, nozzle: NozzleModel) -> SpotPath:
    """The spot path for nozzle poses (K, 4, 4), in the order they are run.

    ``rays`` is a :class:`cellctl.planning.raycast.RayCaster` of the bin mesh (bin frame): a jet
    blocked by a wall washes the wall, not the face behind it.
    """
    T = np.asarray(T_bin_noz, np.float64).reshape(-1, 4, 4)
    tips, axes = T[:, :3, 3], T[:, :3, 2]
    near, far = nozzle.working_distance_m
    _, dist = rays.first_hit(tips, axes)
    ok = (dist >= near * 0.999) & (dist <= far * 1.001)
    # a pose whose jet axis passes just beyond an edge still washes the edge with the rest of
    # its cylinder: its spot sample sits at the sweep's typical stand-off (the preferred one
    # when the whole sweep runs along an edge)
    d = np.where(ok, dist, float(np.median(dist[ok])) if ok.any() else nozzle.distances[0])
    return SpotPath(tips + d[:, None] * axes, axes, float(np.min(nozzle.spot_radius(d))))


def plan_spots(plan: WashPlan, mesh: BinMesh, nozzle: NozzleModel) -> list[SpotPath]:
    """The plan's sweeps, in order, as spot paths (each sweep ``passes`` times, back and forth)."""
    from cellctl.planning.raycast import RayCaster

    rays = RayCaster(mesh.vertices, mesh.faces)
    out: list[SpotPath] = []
    for sw in plan.sweeps:
        one = spray_path(sw.T_bin_noz, rays, nozzle)
        back = one.reversed()
        out.extend(one if k % 2 == 0 else back for k in range(sw.passes))
    return out
