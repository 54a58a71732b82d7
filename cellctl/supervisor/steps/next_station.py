"""next_station: the whole-bin cycle's loop — the next surface at this station, else the next station.

A single-station cycle (``planner.whole.enabled: false``) has one station and one surface:
always ``done``. The loop's place is on the blackboard (``station_index`` in the visiting order,
``surface_index`` in the station's surfaces), so a Hold or Suspend resumes at the station and
viewpoint where it stopped (scanning goes on from ``next_viewpoint``).
"""

from __future__ import annotations

from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import Step


class NextStation(Step):
    NAME = "next_station"
    OUTCOMES = ("next_surface", "next_station", "done")
    DESCRIPTION = "whole-bin cycle: scan the station's next surface, else park at the next station, else report"
    READS = ("station_index", "surface_index")
    WRITES = (
        "station_index",
        "surface_index",
        "next_viewpoint",
        "approach",
        "identify_attempts",
        "observation_index",
    )

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        st = ctx.current_station()
        if st is None:
            return "done"
        ctx.next_viewpoint = 0
        if ctx.surface_index + 1 < len(ctx.station_surfaces(st)):
            ctx.surface_index += 1
            return "next_surface"
        ctx.surface_index = 0
        ctx.station_index += 1
        while (nxt := ctx.current_station()) is not None and not ctx.station_surfaces(nxt):
            ctx.station_notes[nxt.station] = "skipped: the plan has no viewpoints at this station"
            ctx.station_index += 1
        if nxt is None:
            ctx.station_index = len(ctx.station_order)
            return "done"
        ctx.approach = None  # the base drives: park at the next station
        ctx.identify_attempts = 0
        ctx.observation_index = nxt.observation_index or 0
        return "next_station"
