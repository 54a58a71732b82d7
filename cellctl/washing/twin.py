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
from cellctl.washing.spots import SpotPath, plan_spots, spray_path

__all__ = ["spray_pass", "spray_passes", "wash_in_twin"]


def _pass(path: SpotPath, nozzle: NozzleModel) -> SprayPass:
    cos_inc = math.cos(math.radians(nozzle.max_incidence_deg))
    return SprayPass(path.spots, path.axes, path.radius, cos_inc, nozzle.removal_per_pass)


def spray_pass(T_bin_noz: NDArray[np.float64], rays: Any, nozzle: NozzleModel) -> SprayPass:
    """One pass of the jet along nozzle poses (K, 4, 4), in the order they are run."""
    return _pass(spray_path(T_bin_noz, rays, nozzle), nozzle)


def spray_passes(plan: WashPlan, mesh: BinMesh, nozzle: NozzleModel) -> list[SprayPass]:
    """The plan's sweeps, in order, as spray passes (each sweep ``passes`` times, back and forth)."""
    return [_pass(p, nozzle) for p in plan_spots(plan, mesh, nozzle)]


def wash_in_twin(field: PowderField, plan: WashPlan, mesh: BinMesh, nozzle: NozzleModel) -> int:
    """Run the plan's passes over the twin's powder; returns the number of passes run."""
    passes = spray_passes(plan, mesh, nozzle)
    for sp in passes:
        field.wash(sp)
    return len(passes)
