"""The cycle index ``logs/cells.db`` (SQLite, WAL): one row per cycle, the audit index.

Each finished row carries the sha256 of its MCAP and a hash chained to the previous finished
row, so an edited, deleted or reordered record is detectable (``cellctl audit verify``).

Row formats (``row_format``; the chained hash covers exactly the fields of the row's format):

* 1 (``NULL``, rows written before recovery existed): cycle_id … log_sha256.
* 2: format 1 + ``row_format`` and the recovery of an interrupted cycle's log: the recovered
  file's path and sha256, its message count, the original's size and where it was cut. Rows of
  other outcomes carry them as NULL. An index of format-1 rows gains the columns on open; its
  old rows keep their format and their hashes.
"""

from __future__ import annotations

import json
import sqlite3
import threading
from dataclasses import asdict, dataclass
from pathlib import Path

from cellctl.errors import RecordingError
from cellctl.hashing import bytes_sha256, file_sha256_or_none
from cellctl.messages import now_iso
from cellctl.recording.recover import recover_mcap

__all__ = ["ROW_FORMAT", "CycleIndex", "CycleRow", "Recovered"]

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
    row_hash   TEXT,
    row_format INTEGER,
    recovered_path     TEXT,
    recovered_sha256   TEXT,
    recovered_messages INTEGER,
    log_bytes          INTEGER,
    log_intact_bytes   INTEGER
);
"""

ROW_FORMAT = 2
# Columns added by row format 2, in table order (ALTER TABLE appends them to a format-1 index).
_V2_COLUMNS = (
    ("row_format", "INTEGER"),
    ("recovered_path", "TEXT"),
    ("recovered_sha256", "TEXT"),
    ("recovered_messages", "INTEGER"),
    ("log_bytes", "INTEGER"),
    ("log_intact_bytes", "INTEGER"),
)

GENESIS = "0" * 64


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
    # Row format 2 (defaults: a format-1 row read from an index that lacks the columns).
    row_format: int | None = None
    recovered_path: str | None = None
    """The valid, indexed copy of an interrupted cycle's cut-short log (``log_path`` stays as found)."""
    recovered_sha256: str | None = None
    recovered_messages: int | None = None
    log_bytes: int | None = None
    """Size of ``log_path`` as found when the row closed (interrupted rows)."""
    log_intact_bytes: int | None = None
    """How many leading bytes of ``log_path`` are complete records: the cut is there."""

    def chained_fields(self) -> dict[str, object]:
        d = asdict(self)
        for k in ("seq", "prev_hash", "row_hash"):
            d.pop(k)
        if self.row_format is None:  # format 1: hashed before these fields existed
            for k, _ in _V2_COLUMNS:
                d.pop(k)
        return d

    @property
    def readable_log(self) -> str:
        """The log to read: the recovered copy for an interrupted cycle, else ``log_path``."""
        return self.recovered_path or self.log_path


@dataclass(frozen=True)
class Recovered:
    """The recovery of a cut-short log, as a row records it (all None: nothing was recovered)."""

    path: str | None = None
    sha256: str | None = None
    messages: int | None = None
    log_bytes: int | None = None
    log_intact_bytes: int | None = None


def row_hash(prev_hash: str, row: CycleRow) -> str:
    body = json.dumps(row.chained_fields(), sort_keys=True, separators=(",", ":"))
    return bytes_sha256((prev_hash + body).encode())


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
            self._add_v2_columns()
        except sqlite3.Error as err:
            raise RecordingError(f"cannot open cycle index {str(self.path)!r}: {err}") from err

    def _add_v2_columns(self) -> None:
        have = {r[1] for r in self._db.execute("PRAGMA table_info(cycles)")}
        for name, kind in _V2_COLUMNS:
            if name not in have:
                try:
                    self._db.execute(f"ALTER TABLE cycles ADD COLUMN {name} {kind}")
                except sqlite3.OperationalError as err:  # another process added it first
                    if "duplicate column" not in str(err):
                        raise

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
        recovery: Recovered | None = None,
    ) -> CycleRow:
        """Close the row: outcome, verdict, MCAP sha256 (and its recovery) and the chained hash.

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
                rc = recovery or Recovered()
                cur = self._db.execute(
                    "UPDATE cycles SET finished=?, outcome=?, verdict=?, bin_type=?, plan_id=?, reason=?,"
                    " log_sha256=?, prev_hash=?, row_format=?, recovered_path=?, recovered_sha256=?,"
                    " recovered_messages=?, log_bytes=?, log_intact_bytes=? WHERE cycle_id=? AND outcome IS NULL",
                    (
                        finished or now_iso(),
                        outcome,
                        verdict,
                        bin_type,
                        plan_id,
                        reason,
                        log_sha256,
                        prev_hash,
                        ROW_FORMAT,
                        rc.path,
                        rc.sha256,
                        rc.messages,
                        rc.log_bytes,
                        rc.log_intact_bytes,
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
        """Close every row left running by a crash as ``interrupted``; return them (after).

        A log the crash left without its footer is recovered first into a valid, indexed MCAP
        beside it (``recording.recover``); the row records the original as found (sha256, size,
        where it was cut) and the recovered copy (path, sha256, messages). Blocking: reads and
        rewrites each such log once.
        """
        running = self._rows("WHERE outcome IS NULL ORDER BY seq")
        out = []
        for row in running:
            path = Path(row.log_path)
            sha = file_sha256_or_none(path) if row.log_path else None
            reason = "supervisor stopped during the cycle"
            recovered = None
            if sha is not None:
                try:
                    r = recover_mcap(path)
                except RecordingError as err:
                    reason += f"; its log could not be recovered: {err}"
                else:
                    if r.had_footer:  # the crash came after the log closed: it is whole
                        Path(r.out).unlink(missing_ok=True)
                    else:
                        sha = r.source_sha256  # the bytes that were recovered, hashed once
                        recovered = Recovered(r.out, r.out_sha256, r.messages, r.source_bytes, r.intact_bytes)
                        reason += f"; log cut at {r.stopped}; {r.messages} messages recovered into {r.out}"
            out.append(self.finish(row.cycle_id, "interrupted", reason=reason, log_sha256=sha, recovery=recovered))
        return out

    def last(self, n: int = 20) -> list[CycleRow]:
        return list(reversed(self._rows("ORDER BY seq DESC LIMIT ?", (n,))))

    def get(self, cycle_id: str) -> CycleRow | None:
        rows = self._rows("WHERE cycle_id=?", (cycle_id,))
        return rows[0] if rows else None

    def all(self) -> list[CycleRow]:
        return self._rows("ORDER BY seq")
