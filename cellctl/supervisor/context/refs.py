"""Reference sets (steps/references.py): written by a commissioning cycle, looked up by the others."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cellctl.messages import CommissionResult, DecisionPath

if TYPE_CHECKING:
    from cellctl.recording.references import ReferenceManifest, ReferenceSetWriter

__all__ = ["Refs"]


@dataclass
class Refs:
    """Written by scanning (a commissioning cycle's writer; the sets its views are compared with) and
    references (decision path, commission)."""

    writer: ReferenceSetWriter | None = None
    """Mode commission: the reference set the scan stores its views in (claimed by the references step)."""
    decision_path: dict[str, DecisionPath] | None = None
    reference_version: int | None = None
    commission: CommissionResult | None = None
    sets: dict[str, tuple[ReferenceManifest, Path] | None] = field(default_factory=dict)
    """plan id → the newest complete reference set holding it and its folder (None: none), resolved at the
    plan's first view: a set never changes once written, and a cycle commissions its own only after its scan."""
    caster: Any = None
    """The ray caster (:class:`cellctl.classify.heatmap.MeshCaster`) of the cycle's bin mesh, built at the first
    reference comparison: the viewed plane of each reference."""
