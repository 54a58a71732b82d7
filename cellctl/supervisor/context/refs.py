"""Reference sets (steps/references.py): written by a commissioning cycle, looked up by the others."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from cellctl.messages import CommissionResult, DecisionPath

if TYPE_CHECKING:
    from cellctl.recording.references import ReferenceSetWriter

__all__ = ["Refs"]


@dataclass
class Refs:
    """Written by scanning (a commissioning cycle's writer) and references (decision path, commission)."""

    writer: ReferenceSetWriter | None = None
    """Mode commission: the reference set the scan stores its views in (claimed by the references step)."""
    decision_path: dict[str, DecisionPath] | None = None
    reference_version: int | None = None
    commission: CommissionResult | None = None
