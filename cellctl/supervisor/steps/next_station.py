"""next_station: the whole-bin cycle's loop — the next surface at this station, else the next station.

A single-station cycle (``planner.whole.enabled: false``) has one station and one surface:
always ``done``. The loop's place is on the blackboard (``station_index`` in the visiting order,
``surface_index`` in the station's surfaces), so a Hold or Suspend resumes at the station and
viewpoint where it stopped (scanning goes on from ``next_viewpoint``).
"""

from __future__ import annotations

from cellctl.supervisor.context import StepRun
from cellctl.supervisor.steps._base import AT_STATION, Step


class NextStation(Step):
    NAME = "next_station"
    OUTCOMES = ("next_surface", "next_station", "done")
    DESCRIPTION = "whole-bin cycle: scan the station's next surface, else park at the next station, else report"
    READS = ("stations.station_index", "stations.surface_index", "stations.station_notes")
    CONSULTS = AT_STATION
    WRITES = (
        "stations.station_index",
        "stations.surface_index",
        "stations.station_notes",
        "scan.next_viewpoint",
        "identity.approach",
        "identity.identify_attempts",
        "identity.observation_index",
    )

    def execute(self, run: StepRun) -> str:
        ctx = run.ctx
        st = ctx.stations.current_station()
        if st is None:
            return "done"
        ctx.scan.next_viewpoint = 0
        if ctx.stations.surface_index + 1 < len(ctx.stations.station_surfaces(st)):
            ctx.stations.surface_index += 1
            return "next_surface"
        ctx.stations.surface_index = 0
        ctx.stations.station_index += 1
        while (nxt := ctx.stations.current_station()) is not None and not ctx.stations.station_surfaces(nxt):
            ctx.stations.station_notes[nxt.station] = "skipped: the plan has no viewpoints at this station"
            ctx.stations.station_index += 1
        if nxt is None:
            ctx.stations.station_index = len(ctx.stations.station_order)
            return "done"
        ctx.identity.approach = None  # the base drives: park at the next station
        ctx.identity.identify_attempts = 0
        ctx.identity.observation_index = nxt.observation_index or 0
        return "next_station"
