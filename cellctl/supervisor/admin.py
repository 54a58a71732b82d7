"""PackML Admin / PackTags counters of the cell (``Status.admin``), persistent through the cycle index."""

from __future__ import annotations

from collections.abc import Sequence

from cellctl.messages import MAX_WARNINGS, Admin, CycleOutcome, CycleResult, LastCycle
from cellctl.recording.index import CycleIndex

__all__ = ["AdminBook"]


class AdminBook:
    """Bins inspected and bins dirty, the last stop reason, current warnings, the last cycle.

    The counters start from the cycle index (so they survive a daemon restart) and count every
    cycle that ended with outcome ``completed``; ``prod_defective_count`` those with verdict dirty (an
    ``incomplete`` bin is inspected, not defective: ``last_cycle`` says how much of it was seen).
    """

    def __init__(self, index: CycleIndex | None = None) -> None:
        self.processed = 0
        self.defective = 0
        self.stop_reason: str | None = None
        self.last: LastCycle | None = None
        self._warnings: dict[str, str] = {}  # key -> text, insertion-ordered
        if index is not None:
            for row in index.all():
                if row.outcome == CycleOutcome.completed.value:
                    self.processed += 1
                    self.defective += row.verdict == "dirty"
                if row.outcome is not None and row.finished is not None:
                    self.last = LastCycle(
                        cycle_id=row.cycle_id, outcome=row.outcome, verdict=row.verdict, finished=row.finished
                    )

    def cycle_finished(self, res: CycleResult) -> None:
        if res.outcome == CycleOutcome.completed:
            self.processed += 1
            self.defective += res.verdict == "dirty"
        self.last = LastCycle.of(res)

    def warn(self, key: str, text: str | None) -> None:
        """Set (or with None clear) the warning ``key``; at most :data:`MAX_WARNINGS` are kept."""
        if text is None:
            self._warnings.pop(key, None)
        else:
            self._warnings[key] = text

    def snapshot(self, current: Sequence[str] = ()) -> Admin:
        """Admin now; ``current`` are warnings of the moment (e.g. workers not alive), listed first."""
        return Admin(
            prod_processed_count=self.processed,
            prod_defective_count=self.defective,
            stop_reason=self.stop_reason,
            warnings=[*current, *self._warnings.values()][:MAX_WARNINGS],
            last_cycle=self.last,
        )
