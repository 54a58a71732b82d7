"""The cycle index ``logs/cells.db`` (SQLite, WAL): one row per cycle, the audit index.

Each finished row carries the sha256 of its MCAP and a hash chained to the previous finished
row, so an edited, deleted or reordered record is detectable (``cellctl audit verify``).
"""

from __future__ import annotations

import hashlib
import json
import sqlite3
import threading
from dataclasses import asdict, dataclass
from pathlib import Path

from cellctl.errors import RecordingError
from cellctl.messages import now_iso

__all__ = ["CycleIndex", "CycleRow", "file_sha256"]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS cycles (
    seq        INTEGER PRIMARY KEY AUTOINCREMENT,
    cycle_id   TEXT UNIQUE NOT NULL,
    cell       TEXT NOT NULL,
    started    TEXT NOT NULL,
    finished   TEXT,
    outcome    TEXT,
    verdict    TEXT,
    bin_type   TEXT,
    plan_id    TEXT,
    reason     TEXT,
    log_path   TEXT NOT NULL,
    log_sha256 TEXT,
    prev_hash  TEXT,
    row_hash   TEXT
);
"""

GENESIS = "0" * 64


def file_sha256(path: Path) -> str | None:
    try:
        h = hashlib.sha256()
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
        return h.hexdigest()
    except OSError:
        return None


@dataclass(frozen=True)
class CycleRow:
    seq: int
    cycle_id: str
    cell: str
    started: str
    finished: str | None
    outcome: str | None
    verdict: str | None
    bin_type: str | None
    plan_id: str | None
    reason: str | None
    log_path: str
    log_sha256: str | None
    prev_hash: str | None
    row_hash: str | None

    def chained_fields(self) -> dict[str, object]:
        d = asdict(self)
        for k in ("seq", "prev_hash", "row_hash"):
            d.pop(k)
        return d


def row_hash(prev_hash: str, row: CycleRow) -> str:
    body = json.dumps(row.chained_fields(), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256((prev_hash + body).encode()).hexdigest()


class CycleIndex:
    """SQLite index of cycles. Thread-safe; every write is its own transaction."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.executescript(_SCHEMA)
        except sqlite3.Error as err:
            raise RecordingError(f"cannot open cycle index {str(self.path)!r}: {err}") from err

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def _rows(self, sql: str, args: tuple = ()) -> list[CycleRow]:
        with self._lock:
            cur = self._db.execute(f"SELECT * FROM cycles {sql}", args)
            return [CycleRow(*r) for r in cur.fetchall()]

    def begin(self, cycle_id: str, cell: str, log_path: str, started: str | None = None) -> None:
        """Insert the row of a starting cycle (outcome NULL = running)."""
        with self._lock:
            self._db.execute(
                "INSERT INTO cycles (cycle_id, cell, started, log_path) VALUES (?, ?, ?, ?)",
                (cycle_id, cell, started or now_iso(), log_path),
            )

    def finish(
        self,
        cycle_id: str,
        outcome: str,
        *,
        verdict: str | None = None,
        bin_type: str | None = None,
        plan_id: str | None = None,
        reason: str | None = None,
        log_sha256: str | None = None,
        finished: str | None = None,
    ) -> CycleRow:
        """Close the row: outcome, verdict, MCAP sha256 and the chained hash.

        One transaction: a crash between setting the outcome and the hash would leave a closed
        row without a hash, which ``mark_interrupted`` does not pick up and the audit reports.
        """
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                prev = self._db.execute(
                    "SELECT row_hash FROM cycles WHERE row_hash IS NOT NULL ORDER BY seq DESC LIMIT 1"
                ).fetchone()
                prev_hash = prev[0] if prev else GENESIS
                cur = self._db.execute(
                    "UPDATE cycles SET finished=?, outcome=?, verdict=?, bin_type=?, plan_id=?, reason=?,"
                    " log_sha256=?, prev_hash=? WHERE cycle_id=? AND outcome IS NULL",
                    (
                        finished or now_iso(),
                        outcome,
                        verdict,
                        bin_type,
                        plan_id,
                        reason,
                        log_sha256,
                        prev_hash,
                        cycle_id,
                    ),
                )
                r = self._db.execute("SELECT * FROM cycles WHERE cycle_id=?", (cycle_id,)).fetchone()
                if r is None:
                    raise RecordingError(f"cycle {cycle_id!r} is not in the index")
                if cur.rowcount == 0:
                    # Re-closing a chained row would re-chain it and break every link after it.
                    raise RecordingError(
                        f"cycle {cycle_id!r} is already closed (outcome {r[5]!r}); expected a running row"
                    )
                row = CycleRow(*r)
                h = row_hash(prev_hash, row)
                self._db.execute("UPDATE cycles SET row_hash=? WHERE cycle_id=?", (h, cycle_id))
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
            self._db.execute("COMMIT")
        return CycleRow(**{**asdict(row), "row_hash": h})

    def mark_interrupted(self) -> list[CycleRow]:
        """Close every row left running by a crash as ``interrupted``; return them (after)."""
        running = self._rows("WHERE outcome IS NULL ORDER BY seq")
        out = []
        for row in running:
            sha = file_sha256(Path(row.log_path)) if row.log_path else None
            out.append(
                self.finish(row.cycle_id, "interrupted", reason="supervisor stopped during the cycle", log_sha256=sha)
            )
        return out

    def last(self, n: int = 20) -> list[CycleRow]:
        return list(reversed(self._rows("ORDER BY seq DESC LIMIT ?", (n,))))

    def get(self, cycle_id: str) -> CycleRow | None:
        rows = self._rows("WHERE cycle_id=?", (cycle_id,))
        return rows[0] if rows else None

    def all(self) -> list[CycleRow]:
        return self._rows("ORDER BY seq")
