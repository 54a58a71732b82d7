"""Wash planning: a dirt map → raster sweeps of the nozzle over the dirty regions, ordered.

The inspection planner's stages, called with the nozzle instead of the camera (paper §IV: "replacing
the inspection camera … with a washing nozzle and changing the camera pin-hole model with the
model defining the nozzle frustum of action"):

====================================  ===============================================================
step                                  what runs
====================================  ===============================================================
targets                               faces ≥ threshold (or ``seen_dirty``), dilated by the margin
                                      (:mod:`cellctl.washing.targets`), regions and facets
seeds                                 raster waypoints on each facet: lines ``footprint·(1−overlap)``
                                      apart, a waypoint every half line spacing
viewpoints + filters                  :func:`~cellctl.planning.viewpoints.generate_viewpoints` at the
                                      nozzle's stand-offs (jet along −normal), the planner's height,
                                      distance, occlusion and camera-body filters, plus the lance
reachability                          :func:`~cellctl.planning.reach.reachability` with the robot's
                                      tool frame at the nozzle (:meth:`NozzleModel.robot_with_nozzle`),
                                      then :func:`~cellctl.planning.whole.connect`: only arm
                                      configurations joined to home by straight free motions
visibility → sprayed                  :func:`~cellctl.planning.visibility.measurability` with the
                                      nozzle's frustum camera, cut to the cone and footprint
sweeps                                runs of consecutive reachable waypoints of one raster line
                                      joined by short collision-free joint motions
set cover                             greedy multi-cover over sweeps: every target face gets
                                      ``required_passes`` sweeps (a sweep may be chosen again:
                                      it is then run back and forth)
tour                                  :func:`~cellctl.planning.tour.ant_colony` + 2-opt over the
                                      sweeps from the start configuration; transit motions checked
====================================  ===============================================================

Target faces no sweep sprays are **unwashable**, grouped by region with the stage that lost them.
No dirt map → a plan with no passes and the reason (no motion). Frames: bin frame, nozzle
frame +Z along the jet. Metres, radians.

Modules: :mod:`.records` (parameters, sweeps, the plan), :mod:`.seeds` (raster waypoints, residue
candidates, demand points, nozzle poses), :mod:`.station` (one station's stages, from waypoints to
its toured sweeps), :mod:`.budget` (the CPU ceiling), :mod:`.pipeline` (:func:`plan_wash`, the sequence).
"""

from cellctl.washing.plan.pipeline import plan_wash
from cellctl.washing.plan.records import MAX_SWEEP_STEP_RAD, Sweep, Unwashable, WashParams, WashPlan

__all__ = ["MAX_SWEEP_STEP_RAD", "Sweep", "Unwashable", "WashParams", "WashPlan", "plan_wash"]
