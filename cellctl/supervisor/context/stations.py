"""The whole-bin cycle's station loop (``planner.whole.enabled``): its place and what each station gave."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cellctl.messages import PlanLookupReply, StationInfo
from cellctl.surface import SURFACES, Surface

__all__ = ["PlanKey", "Stations"]

PlanKey = tuple[int | None, str | None]
"""(station, surface) of a plan scanned; a single-station cycle's one plan is keyed (None, None)."""


@dataclass
class Stations:
    """Written by checking_cache (the loop's start), identifying (the poses), next_station (the place)."""

    planned: list[StationInfo] | None = None
    """The whole-bin plan's stations, from the first lookup; None until then (and in a single-station cycle)."""
    station_order: list[int] = field(default_factory=list)
    """Station ranks in visiting order (starting where the first park was identified)."""
    station_index: int = 0
    """Position in ``station_order`` of the station the cycle is at (Hold/Suspend resume here)."""
    surface_index: int = 0
    """Position in the current station's surfaces (:meth:`station_surfaces`)."""
    whole_plan_id: str | None = None
    modelled_cycle_s: float | None = None
    plans: dict[PlanKey, PlanLookupReply] = field(default_factory=dict)
    """(station, surface) → the plan scanned there; single-station cycles use key (None, None)."""
    bin_poses: dict[int, np.ndarray] = field(default_factory=dict)
    """station → T_base_bin used there (measured, or the planned station pose when carried over)."""
    pose_source: dict[int, str] = field(default_factory=dict)
    T_map_base: np.ndarray | None = None
    """The base's reported pose (its localisation, ApproachReply.base_pose) at the current park; None: no report."""
    T_map_bin: np.ndarray | None = None
    """The bin in the base's map frame, from the latest pose measured with a base report (base_odometry)."""
    station_coverage: dict[PlanKey, float | None] = field(default_factory=dict)
    station_notes: dict[int, str] = field(default_factory=dict)

    def current_station(self) -> StationInfo | None:
        """The station the whole-bin cycle is at, or None (single-station cycle, or stations not known yet)."""
        if not self.planned or self.station_index >= len(self.station_order):
            return None
        rank = self.station_order[self.station_index]
        return next(s for s in self.planned if s.station == rank)

    def station_surfaces(self, st: StationInfo | None = None) -> list[Surface]:
        """The surfaces a station has viewpoints for, in :data:`~cellctl.surface.SURFACES` order."""
        st = st if st is not None else self.current_station()
        return [s for s in SURFACES if st is not None and s in st.plans]
