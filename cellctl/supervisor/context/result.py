"""What the cycle concludes: the CycleResult's verdict, coverage, dirt map, outcome and reason."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from cellctl.messages import CycleOutcome
from cellctl.seen import Verdict

__all__ = ["Result"]


@dataclass
class Result:
    """Written by classifying and reporting (the verdict, the map), wash_check and verifying (after a wash),
    replanning (``replan_required``); the supervisor writes outcome and reason when it ends a cycle."""

    verdict: Verdict | None = None
    coverage: float | None = None
    coverage_by_surface: dict[str, float | None] | None = None
    dirt_map: dict[str, Any] | None = None
    """JSON for the CycleResult, as recording.dirt_map reads it."""
    outcome: CycleOutcome | None = None
    reason: str | None = None
