"""Start mode ``wash_and_verify``: the rounds, and the place in the running one (steps/washing.py, verifying.py)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cellctl.messages import PlannedSweep, ViewpointResult, WashPlanReply, WashResult, WashRound

__all__ = ["Wash"]


@dataclass
class Wash:
    """Written by wash_check (a round's plan), wash_station (the walk), washing (sweeps) and verifying.

    A whole-bin round washes from, then re-inspects from, each station it needs; a single-station
    cycle uses the one entry None in the queues.
    """

    plan: WashPlanReply | None = None
    """The round's wash plan (the planner worker's reply) while it is washed and re-inspected."""
    rounds: list[WashRound] = field(default_factory=list)
    run: dict[str, Any] = field(default_factory=dict)
    """The running round's counts: sweeps and passes run, sweeps refused, its pictures so far."""
    next_sweep: int = 0
    next_view: int = 0
    result: WashResult | None = None
    """The CycleResult's ``wash``: the rounds and, once wash_check decides, the verdict."""
    phase: str = "wash"
    """``wash`` (running the sweeps station by station) or ``verify`` (re-inspecting) within a round."""
    queue: list[int | None] = field(default_factory=list)
    """Stations still to wash from this round, in order (the head is the one washed or parked for now)."""
    verify_queue: list[int | None] = field(default_factory=list)
    """Stations still to re-inspect from this round, in order."""
    parked: int | None = None
    """The station the base is parked at while washing and re-inspecting (None: single-station)."""
    scan_poses: dict[int, np.ndarray] = field(default_factory=dict)
    """station → T_base_bin the scan's plans were adjusted to (a re-park measures a new one)."""
    station_sweeps: dict[int | None, list[PlannedSweep]] = field(default_factory=dict)
    """station → this round's sweeps to run there (absent: plan them at the station's new park)."""
    views: list[ViewpointResult] = field(default_factory=list)
    """The re-inspection views (``wash_round`` set): in the MCAP and the rounds' counts, not in the
    CycleResult's ``viewpoints`` (a whole-bin wash cycle's would pass the 64 KiB wire limit)."""
