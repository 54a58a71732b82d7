"""Whole-bin planning: several stations, both surfaces, every viewpoint connected (issue 19).

:func:`plan_whole` runs, per surface, the single-station pipeline's first stages once
(seeds, viewpoints, filters: they do not depend on the base) and measures the **upper bound**:
the area properly visible from any filtered camera pose, ignoring the arm. Then per candidate
station (:mod:`cellctl.planning.stations`): the distance filter, reachability (IK + collision,
parking robustness) and **connection** (:func:`connect`), then visibility. Stations are chosen
by a set cover over (station, viewpoint) pairs; Greedy Area + SA select viewpoints over the
chosen stations' pairs of each surface; each station's share is ordered by a tour whose cost is
**motion time** (:mod:`cellctl.motion`, UR10e velocity and acceleration limits × speed fraction).

Connected = the station's start configuration (the arm's home, the "candle" the base drives
with) reaches the viewpoint's configuration by a straight joint motion that is collision-free
at the sim arm's own check step (:data:`cellctl.sim.motion.STEP_RAD`). A viewpoint whose chosen
IK solution is not connected is replaced, before selection, by its next-best solution (other
rolls, IK solutions of the same arm shape, the next distance) that is; only when none is, the
direction is left out (counted in ``unconnected_directions``). So every tour edge has a real
motion: straight, or via home (two straight motions) when the straight one collides — which is
also what the sim arm falls back to (``_plan`` via home) — and no selected viewpoint is dropped
after selection (``dropped_unconnected`` = 0 by construction; it is still counted).

The result is a :class:`WholePlan`: ordered stations, each with its identification pose and
one ordinary :class:`~cellctl.planning.plan.Plan` per surface at that station's base pose — so
the plan cache, the pose tolerance and the adjustment work per station unchanged.

Modules, one concept each (the stages in order: :mod:`.pipeline`'s table):

- :mod:`.records`: parameters, the timing model, the plan records, the plan file;
- :mod:`.connection`: viewpoints joined to home by straight free motions, the 2π window;
- :mod:`.timing`: timed tours, detours, IK refinement, the whole-tour shift;
- :mod:`.chains`: which chain viewpoints a tour visits, make-up, the coverage floor, the gain rule;
- :mod:`.state`: the state the stages share, a station's evaluation;
- :mod:`.evaluation`, :mod:`.selection`, :mod:`.tours`, :mod:`.budget`: the stages;
- :mod:`.pipeline`: :func:`plan_whole`, the sequence.
"""

from cellctl.planning.whole.connection import chain_to_start, connect, wrap_window
from cellctl.planning.whole.pipeline import plan_whole
from cellctl.planning.whole.records import (
    WHOLE_FORMAT,
    StationPlan,
    SurfaceSummary,
    TimingModel,
    WholeParams,
    WholePlan,
    read_whole,
    whole_path,
    write_whole,
)

__all__ = [
    "WHOLE_FORMAT",
    "StationPlan",
    "SurfaceSummary",
    "TimingModel",
    "WholeParams",
    "WholePlan",
    "chain_to_start",
    "connect",
    "plan_whole",
    "read_whole",
    "whole_path",
    "wrap_window",
    "write_whole",
]
