"""Cycle recording: one MCAP per cycle (``cycle_log``), the SQLite cycle index (``index``),
its audit (``audit``), Foxglove well-known schemas (``foxglove``)."""

from cellctl.recording.audit import AuditReport, verify_audit
from cellctl.recording.cycle_log import CycleLog
from cellctl.recording.index import CycleIndex, CycleRow

__all__ = ["AuditReport", "CycleIndex", "CycleLog", "CycleRow", "verify_audit"]
