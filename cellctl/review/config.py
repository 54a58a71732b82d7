"""The ``review:`` section of the cell config: release gating and the reviewed-view bank.

In the cell config, not the HMI's own file, because two processes read it: the HMI (which gates
the release of a verdict) and ``cellctl detector update`` (which re-enrolls from the bank). Leaf
module (pydantic only): the daemon's config imports it.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, StrictBool

from cellctl.strict_model import ConfigModel

__all__ = ["ReviewConfig"]


class ReviewConfig(ConfigModel):
    """Operator review of uncertain and dirty views (docs/hmi/README.md, "Review")."""

    require_for_uncertain: StrictBool = Field(
        default=True,
        description="a completed cycle with an uncertain view is released only by review (every uncertain view "
        "confirmed clean or dirty, then Release); false: every completed cycle's verdict stands released",
    )
    dir: Path | None = Field(
        default=None,
        description="the reviewed-view bank (images + manifest.json); default <recording.dir>/review",
    )
    max_per_label: int = Field(
        default=500,
        ge=10,
        le=100_000,
        description="views kept per surface and label; beyond it the oldest decision's view is evicted "
        "(its provenance stays in the review ledger)",
    )
    queue_cycles: int = Field(
        default=50, ge=1, le=1000, description="the newest completed cycles the review queue looks at"
    )
