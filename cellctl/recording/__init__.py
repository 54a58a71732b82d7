"""Cycle recording: one MCAP per cycle (``cycle_log``), the SQLite cycle index (``index``),
Foxglove well-known schemas (``foxglove``)."""

from cellctl.recording.cycle_log import CycleLog
from cellctl.recording.index import CycleIndex, CycleRow

__all__ = ["CycleIndex", "CycleLog", "CycleRow"]
