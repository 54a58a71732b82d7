"""The plan scanned now and the views the scan took of it."""

from __future__ import annotations

from concurrent.futures import Future
from dataclasses import dataclass, field

from cellctl.messages import ClassifyReply, PlanLookupReply, ViewpointResult

__all__ = ["Scan"]


@dataclass
class Scan:
    """Written by checking_cache (the plan), replanning (its job), scanning and classifying (the views)."""

    plan: PlanLookupReply | None = None
    """The plan of the current station and surface (single-station: the cycle's one plan)."""
    planner_job_id: str | None = None
    next_viewpoint: int = 0
    """The plan's next viewpoint to visit (a Hold resumes here)."""
    viewpoints: list[ViewpointResult] = field(default_factory=list)
    """Every view of the scan (re-looks included): the CycleResult's ``viewpoints``."""
    classifications: dict[int, Future[ClassifyReply]] = field(default_factory=dict)
    """Position in ``viewpoints`` → its classification, running on the cycle's pool while the robot moves."""
