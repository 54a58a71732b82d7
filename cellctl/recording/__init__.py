"""Cycle recording: one MCAP per cycle (``cycle_log``), the SQLite cycle index (``index``),
its audit (``audit``), the recovery of a cut-short MCAP (``recover``), Foxglove well-known
schemas (``foxglove``)."""

from cellctl.recording.audit import AuditReport, verify_audit
from cellctl.recording.cycle_log import CycleLog
from cellctl.recording.index import CycleIndex, CycleRow
from cellctl.recording.recover import Recovery, recover_mcap

__all__ = ["AuditReport", "CycleIndex", "CycleLog", "CycleRow", "Recovery", "recover_mcap", "verify_audit"]
