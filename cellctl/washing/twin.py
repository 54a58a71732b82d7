"""Washing in the twin: a wash plan's sweeps as spray passes over the sim's powder.

Each sweep is run ``passes`` times, back and forth. The jet's spot along a sweep is where the
jet from each nozzle pose first hits the bin (a ray cast, so a jet blocked by a wall washes the
wall, not the face behind it) within the working distance; the powder model
(:class:`cellctl.sim.ground_truth.PowderField`) then keeps ``1 − removal`` of the powder under
the footprint per pass, so a re-inspection of the twin sees what is left.

Sim-only: imports the ground truth.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.geometry.catalog import BinMesh
from cellctl.sim.ground_truth import PowderField, SprayPass
from cellctl.washing.nozzle import NozzleModel
from cellctl.washing.plan import WashPlan

__all__ = ["spray_pass", "spray_path", "spray_passes", "wash_in_twin"]


def spray_path(T_bin_noz: NDArray[np.float64], rays: Any, nozzle: NozzleModel) -> tuple[NDArray, NDArray, float]:
    """Where the jet's spot runs on the bin for nozzle poses (K, 4, 4): spots (K, 3), axes (K, 3), radius.

    ``rays`` is a :class:`cellctl.planning.raycast.RayCaster` of the bin mesh (bin frame).
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
    return tips + d[:, None] * axes, axes, float(np.min(nozzle.spot_radius(d)))


def spray_pass(T_bin_noz: NDArray[np.float64], rays: Any, nozzle: NozzleModel) -> SprayPass:
    """One pass of the jet along nozzle poses (K, 4, 4), in the order they are run."""
    spots, ax, radius = spray_path(T_bin_noz, rays, nozzle)
    cos_inc = math.cos(math.radians(nozzle.max_incidence_deg))
    return SprayPass(spots, ax, radius, cos_inc, nozzle.removal_per_pass)


def spray_passes(plan: WashPlan, mesh: BinMesh, nozzle: NozzleModel) -> list[SprayPass]:
    """The plan's sweeps, in order, as spray passes (each sweep ``passes`` times, back and forth)."""
    from cellctl.planning.raycast import RayCaster

    rays = RayCaster(mesh.vertices, mesh.faces)
    out: list[SprayPass] = []
    for sw in plan.sweeps:
        one = spray_pass(sw.T_bin_noz, rays, nozzle)
        back = SprayPass(one.spots[::-1].copy(), one.axes[::-1].copy(), one.radius, one.cos_incidence, one.removal)
        out.extend(one if k % 2 == 0 else back for k in range(sw.passes))
    return out


def wash_in_twin(field: PowderField, plan: WashPlan, mesh: BinMesh, nozzle: NozzleModel) -> int:
    """Run the plan's passes over the twin's powder; returns the number of passes run."""
    passes = spray_passes(plan, mesh, nozzle)
    for sp in passes:
        field.wash(sp)
    return len(passes)
