"""Audit of the cycle index and the cycle logs: the hash chain and every MCAP's sha256.

What is checked (``cellctl audit verify``; the reasoning is in docs/decisions.md):

* each closed row's ``row_hash`` against ``sha256(prev_hash + its fields)`` (an edited field);
* each row's ``prev_hash`` against its predecessor in seq order (a deleted or reordered row);
* seq numbers against each other and ``sqlite_sequence`` (a hint of deleted rows);
* each closed row's MCAP against its ``log_sha256`` (an edited, truncated, replaced or missing log);
* an interrupted row's recovered MCAP against its ``recovered_sha256`` (both files are evidence:
  the cut-short original as found, and the valid copy that replay and report read);
* every ``*.mcap`` under the logs folder is referenced by a row (the log of a deleted row);
* optionally, a head hash recorded outside the cell is still in the chain (deleted newest rows);
* the review ledger (``reviews.jsonl`` in the logs folder, :mod:`cellctl.review.ledger`): each
  operator decision and release hashes to its entry hash, links to the one before, and names the
  reviewed cycle's current row hash (a record changed after its review).

Given the reference root, also every reference set (:mod:`cellctl.recording.references`): its
manifest against the sha256 its commissioning cycle's MCAP recorded (that MCAP checked against its
chained row), and every image and enrolled detector file against the manifest.

The index is opened read-only: auditing never changes what it audits.
"""

from __future__ import annotations

import json
import re
import sqlite3
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from enum import StrEnum
from pathlib import Path

from cellctl.errors import RecordingError
from cellctl.hashing import file_sha256_or_none
from cellctl.recording.index import GENESIS, CycleRow, row_hash

__all__ = [
    "AuditFinding",
    "AuditReport",
    "FindingKind",
    "Severity",
    "checked_log",
    "find_cycle",
    "read_head",
    "verify_audit",
]


class Severity(StrEnum):
    tamper = "tamper"
    """The record or log differs from what was written: the audit fails."""
    info = "info"
    """Worth knowing, not a sign of tampering (a cycle still running)."""


class FindingKind(StrEnum):
    row_edited = "row_edited"
    row_unhashed = "row_unhashed"
    row_deleted = "row_deleted"
    rows_reordered = "rows_reordered"
    seq_gap = "seq_gap"
    tail_missing = "tail_missing"
    head_missing = "head_missing"
    log_missing = "log_missing"
    log_mismatch = "log_mismatch"
    log_unrecorded = "log_unrecorded"
    log_orphan = "log_orphan"
    reference_unrecorded = "reference_unrecorded"
    reference_mismatch = "reference_mismatch"
    recovered_missing = "recovered_missing"
    recovered_mismatch = "recovered_mismatch"
    running = "running"
    no_log = "no_log"
    review_edited = "review_edited"
    review_chain = "review_chain"
    review_anchor = "review_anchor"
    review_unreadable = "review_unreadable"


_HEX64 = re.compile(r"[0-9a-f]{64}")
_INFO = {FindingKind.running, FindingKind.no_log}


@dataclass(frozen=True)
class AuditFinding:
    """One thing the audit found; ``message`` names the expected and found values."""

    kind: FindingKind
    message: str
    seq: int | None = None
    cycle_id: str | None = None
    path: str | None = None

    @property
    def severity(self) -> Severity:
        return Severity.info if self.kind in _INFO else Severity.tamper

    def as_dict(self) -> dict[str, object]:
        return {**asdict(self), "kind": self.kind.value, "severity": self.severity.value}


@dataclass
class AuditReport:
    """The result of :func:`verify_audit`; ``ok`` when nothing points at tampering."""

    index: str
    logs_root: str
    rows: int = 0
    logs_checked: int = 0
    head_seq: int | None = None
    head_hash: str | None = None
    findings: list[AuditFinding] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.tampering

    @property
    def tampering(self) -> list[AuditFinding]:
        return [f for f in self.findings if f.severity is Severity.tamper]

    def as_dict(self) -> dict[str, object]:
        return {
            "ok": self.ok,
            "index": self.index,
            "logs_root": self.logs_root,
            "rows": self.rows,
            "logs_checked": self.logs_checked,
            "head": {"seq": self.head_seq, "row_hash": self.head_hash},
            "findings": [f.as_dict() for f in self.findings],
        }


def _open_read_only(index_path: Path) -> sqlite3.Connection:
    if not index_path.is_file():
        raise RecordingError(f"cycle index {str(index_path)!r} does not exist; expected the recording.index file")
    try:
        db = sqlite3.connect(f"{index_path.resolve().as_uri()}?mode=ro", uri=True)
        db.execute("SELECT 1 FROM cycles LIMIT 1").fetchall()
    except sqlite3.Error as err:
        raise RecordingError(f"cannot read cycle index {str(index_path)!r}: {err}") from err
    return db


def _read(index_path: Path) -> tuple[list[CycleRow], int | None]:
    db = _open_read_only(index_path)
    try:
        rows = [CycleRow(*r) for r in db.execute("SELECT * FROM cycles ORDER BY seq")]
        top = db.execute("SELECT seq FROM sqlite_sequence WHERE name='cycles'").fetchone()
    except sqlite3.Error as err:
        raise RecordingError(f"cannot read cycle index {str(index_path)!r}: {err}") from err
    finally:
        db.close()
    return rows, (top[0] if top else None)


def read_head(index_path: Path) -> CycleRow | None:
    """The newest chained row (its ``row_hash`` is the head to export), or None if no cycle closed.

    Raises:
        RecordingError: the index is missing or unreadable.
    """
    rows, _ = _read(Path(index_path))
    chained = [r for r in rows if r.row_hash]
    return chained[-1] if chained else None


def find_cycle(
    index_path: Path | str, *, cycle_id: str | None = None, log: Path | str | None = None
) -> CycleRow | None:
    """The row of ``cycle_id``, or the row whose log or recovered log is the file ``log``; None if none.

    Read-only, like the audit. An index that does not exist holds no row (a log from elsewhere).

    Raises:
        RecordingError: the index exists but is unreadable.
    """
    index_path = Path(index_path)
    if not index_path.is_file():
        return None
    rows, _ = _read(index_path)
    want = Path(log).resolve() if log is not None else None
    for r in rows:
        if cycle_id is not None and r.cycle_id == cycle_id:
            return r
        if want is not None and any(p and Path(p).resolve() == want for p in (r.log_path, r.recovered_path)):
            return r
    return None


def checked_log(row: CycleRow) -> Path:
    """The log to read for ``row`` (the recovered copy of an interrupted cycle), its hashes checked.

    For an interrupted cycle both files are checked: the cut-short original against
    ``log_sha256`` (the evidence) and the recovered copy against ``recovered_sha256``. A row
    still running has no hash yet; its log is returned unchecked.

    Raises:
        RecordingError: a file is missing or differs from the hash its row recorded.
    """
    for finding in (_check_log(row), _check_recovered(row)):
        if finding is not None and finding.severity is Severity.tamper:
            raise RecordingError(f"refusing to read {_name(row)}: {finding.message}")
    return Path(row.readable_log)


def _name(r: CycleRow) -> str:
    return f"cycle {r.cycle_id} (seq {r.seq})"


def _check_rows(rows: list[CycleRow], top_seq: int | None) -> Iterable[AuditFinding]:
    """Row hashes, chain links, seq gaps."""
    chained = [r for r in rows if r.row_hash]
    by_hash = {r.row_hash: r for r in chained}
    broken_at: set[int] = set()
    for r in rows:
        if r.row_hash is None:
            if r.outcome is None:
                yield AuditFinding(
                    FindingKind.running,
                    f"{_name(r)} has no outcome: running now, or left by a crash that the next supervisor"
                    " start marks interrupted",
                    r.seq,
                    r.cycle_id,
                )
            else:
                yield AuditFinding(
                    FindingKind.row_unhashed,
                    f"{_name(r)} is closed (outcome {r.outcome!r}) but has no row_hash; expected a chained hash",
                    r.seq,
                    r.cycle_id,
                )
            continue
        expected = row_hash(r.prev_hash or "", r)
        if expected != r.row_hash:
            yield AuditFinding(
                FindingKind.row_edited,
                f"{_name(r)} fields do not match its row_hash: stored {r.row_hash}, computed {expected}",
                r.seq,
                r.cycle_id,
            )
    for i, r in enumerate(chained):
        pred = chained[i - 1] if i else None
        expected_prev = pred.row_hash if pred else GENESIS
        if r.prev_hash == expected_prev:
            continue
        broken_at.add(r.seq)
        after = f"follows {_name(pred)}" if pred else "is the first row"
        linked = by_hash.get(r.prev_hash) if r.prev_hash else None
        if linked is not None or r.prev_hash == GENESIS:
            kind = FindingKind.rows_reordered
            what = f"{after} in seq order but is chained after {_name(linked) if linked else 'the genesis'}"
        else:
            kind = FindingKind.row_deleted
            since = f"after seq {pred.seq}" if pred else "before it"
            what = f"is chained after a row that is not in the index: rows {since} were deleted"
        yield AuditFinding(
            kind, f"{_name(r)} {what} (prev_hash {r.prev_hash}, expected {expected_prev})", r.seq, r.cycle_id
        )
    for prev, r in zip(rows, rows[1:], strict=False):
        if r.seq != prev.seq + 1 and r.seq not in broken_at:
            yield AuditFinding(
                FindingKind.seq_gap,
                f"seq jumps from {prev.seq} to {r.seq} at {_name(r)}: rows {prev.seq + 1}..{r.seq - 1} were deleted",
                r.seq,
                r.cycle_id,
            )
    last_seq = rows[-1].seq if rows else 0
    if top_seq is not None and top_seq > last_seq:
        yield AuditFinding(
            FindingKind.tail_missing,
            f"the index handed out seq {top_seq} but its last row is seq {last_seq}: the newest"
            f" {top_seq - last_seq} row(s) were deleted",
            last_seq + 1,
        )


def _check_head(rows: list[CycleRow], head: str) -> Iterable[AuditFinding]:
    # GENESIS: exported before any cycle closed, so every row is newer than it.
    if head == GENESIS or any(r.row_hash == head for r in rows):
        return
    chained = [r for r in rows if r.row_hash]
    last = f"{chained[-1].row_hash} at {_name(chained[-1])}" if chained else "none (no closed cycle)"
    yield AuditFinding(
        FindingKind.head_missing,
        f"the exported head {head} is not in the chain (the index head is {last}): the newest rows were"
        " deleted or the chain was rewritten",
    )


def _check_log(r: CycleRow) -> AuditFinding | None:
    path = Path(r.log_path)
    as_found = " (hashed as found when the supervisor restarted)" if r.outcome == "interrupted" else ""
    if r.row_hash is None:
        return None  # running: the file still grows, nothing to compare yet
    if r.log_sha256 is None:
        if path.exists():
            return AuditFinding(
                FindingKind.log_unrecorded,
                f"{_name(r)} recorded no log sha256{as_found}, yet {path} exists: a log appeared after the row closed",
                r.seq,
                r.cycle_id,
                str(path),
            )
        return AuditFinding(
            FindingKind.no_log, f"{_name(r)} has no log: {path} was missing when the row closed", r.seq, r.cycle_id
        )
    return _check_hash(r, "log", path, r.log_sha256, as_found, FindingKind.log_missing, FindingKind.log_mismatch)


def _check_recovered(r: CycleRow) -> AuditFinding | None:
    if r.row_hash is None or r.recovered_path is None:
        return None
    return _check_hash(
        r,
        "recovered log",
        Path(r.recovered_path),
        r.recovered_sha256,
        f" (recovered from {r.log_path} when the supervisor restarted)",
        FindingKind.recovered_missing,
        FindingKind.recovered_mismatch,
    )


def _check_hash(
    r: CycleRow,
    what: str,
    path: Path,
    expected: str | None,
    context: str,
    missing: FindingKind,
    mismatch: FindingKind,
) -> AuditFinding | None:
    found = file_sha256_or_none(path)
    if found is None:
        return AuditFinding(
            missing,
            f"{_name(r)} {what} {path} is missing; expected a file with sha256 {expected}",
            r.seq,
            r.cycle_id,
            str(path),
        )
    if found != expected:
        return AuditFinding(
            mismatch,
            f"{_name(r)} {what} {path} ({path.stat().st_size} bytes) has sha256 {found}, expected"
            f" {expected}{context}: the file was edited, truncated or replaced",
            r.seq,
            r.cycle_id,
            str(path),
        )
    return None


def _recorded_manifest_sha(r: CycleRow) -> str | None:
    """The reference-set manifest sha256 a commissioning cycle's MCAP recorded, or None."""
    from mcap.reader import make_reader

    from cellctl.bus.topics import REFERENCES

    try:
        with open(r.readable_log, "rb") as f:
            for _schema, _channel, msg in make_reader(f).iter_messages(topics=[REFERENCES]):
                sha = json.loads(msg.data).get("manifest_sha256")
                if sha:
                    return str(sha)
    except (OSError, ValueError) as err:  # mcap raises ValueError subclasses on a damaged file
        raise RecordingError(f"{_name(r)} log {r.readable_log} cannot be read for its reference record: {err}") from err
    return None


def _check_references(rows: list[CycleRow], root: Path) -> Iterable[AuditFinding]:
    """Each reference set against its commissioning cycle's record, and its files against its manifest."""
    from cellctl.recording.references import check_set_files, read_manifest

    by_id = {r.cycle_id: r for r in rows}
    for path in sorted(root.glob("*/v*/manifest.json")):
        try:
            man = read_manifest(path)
        except RecordingError as err:
            yield AuditFinding(FindingKind.reference_mismatch, str(err), path=str(path))
            continue
        r = by_id.get(man.cycle_id)
        why = f"cycle {man.cycle_id!r} has no chained row recording it"
        try:
            recorded = _recorded_manifest_sha(r) if r is not None and r.row_hash is not None else None
        except RecordingError as err:
            recorded, why = None, str(err)
        if recorded is None:
            yield AuditFinding(
                FindingKind.reference_unrecorded,
                f"reference set {path.parent} (v{man.version} of {man.bin_type!r}): {why}: a set put there",
                cycle_id=man.cycle_id,
                path=str(path),
            )
        elif (found := file_sha256_or_none(path)) != recorded:
            yield AuditFinding(
                FindingKind.reference_mismatch,
                f"reference manifest {path} has sha256 {found}, cycle {man.cycle_id!r} recorded {recorded}: "
                "edited or replaced",
                cycle_id=man.cycle_id,
                path=str(path),
            )
        for line in check_set_files(path.parent, man):
            yield AuditFinding(FindingKind.reference_mismatch, f"reference set v{man.version}: {line}", path=str(path))


def verify_audit(
    index_path: Path | str,
    logs_root: Path | str,
    head: str | None = None,
    *,
    progress: Callable[[int, int], None] | None = None,
    references: Path | str | None = None,
) -> AuditReport:
    """Check the cycle index chain and every cycle log against it.

    Blocking: reads every MCAP once, in 1 MiB blocks (a large log is never held in memory).

    Args:
        index_path: the SQLite cycle index (``recording.index``); opened read-only.
        logs_root: the folder of the cycle logs (``recording.dir``); every ``*.mcap`` below it
            must belong to a row.
        head: a ``row_hash`` exported earlier (``cellctl audit head``); it must still be in the
            chain. Without it, deleting the newest rows together with their logs is caught only
            by the ``sqlite_sequence`` hint, which an editor can also reset.
        progress: called as ``progress(rows_done, rows_total)`` after each row's log is hashed.
        references: the reference root (:func:`cellctl.recording.references.reference_root`): check
            every reference set too; None: skip them.

    Returns:
        The report; ``report.ok`` is False when any finding points at tampering.

    Raises:
        RecordingError: the index is missing, unreadable or has no ``cycles`` table.
    """
    index_path, logs_root = Path(index_path), Path(logs_root)
    if head is not None and not _HEX64.fullmatch(head):
        raise RecordingError(f"head {head!r} is not a row hash; expected 64 lowercase hex digits (cellctl audit head)")
    rows, top_seq = _read(index_path)
    report = AuditReport(index=str(index_path), logs_root=str(logs_root), rows=len(rows))
    chained = [r for r in rows if r.row_hash]
    if chained:
        report.head_seq, report.head_hash = chained[-1].seq, chained[-1].row_hash
    report.findings.extend(_check_rows(rows, top_seq))
    if head is not None:
        report.findings.extend(_check_head(rows, head))
    if references is not None and Path(references).is_dir():
        report.findings.extend(_check_references(rows, Path(references)))
    referenced: set[Path] = set()
    for i, r in enumerate(rows, 1):
        referenced.add(Path(r.log_path).resolve())
        if r.recovered_path:
            referenced.add(Path(r.recovered_path).resolve())
        if r.row_hash is not None and r.log_sha256 is not None:
            report.logs_checked += 1
        if r.row_hash is not None and r.recovered_path is not None:
            report.logs_checked += 1
        for finding in (_check_log(r), _check_recovered(r)):
            if finding is not None:
                report.findings.append(finding)
        if progress is not None:
            progress(i, len(rows))
    report.findings.extend(_check_reviews(rows, logs_root))
    if logs_root.is_dir():
        for f in sorted(logs_root.rglob("*.mcap")):
            if f.resolve() not in referenced:
                report.findings.append(
                    AuditFinding(
                        FindingKind.log_orphan,
                        f"{f} ({f.stat().st_size} bytes) is referenced by no row of {index_path}: the log of a"
                        " deleted row, or a file put there",
                        path=str(f),
                    )
                )
    return report


def _check_reviews(rows: list[CycleRow], logs_root: Path) -> Iterable[AuditFinding]:
    """The review ledger's findings (module doc); nothing when no view was ever reviewed."""
    from cellctl.review.ledger import LEDGER_NAME, check_ledger

    path = logs_root / LEDGER_NAME
    if not path.is_file():
        return
    kinds = {"edited": FindingKind.review_edited, "chain": FindingKind.review_chain,
             "anchor": FindingKind.review_anchor, "unreadable": FindingKind.review_unreadable}  # fmt: skip
    for p in check_ledger(path, {r.cycle_id: r.row_hash for r in rows}):
        yield AuditFinding(kinds[p.kind], p.message, cycle_id=p.cycle_id, path=str(path))
