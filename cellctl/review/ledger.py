"""The review ledger: every operator decision and release, hash-chained and anchored to the cycle index.

One JSON object per line in ``<recording.dir>/reviews.jsonl``, beside the cycle index it speaks
about (the audit reads both). Each entry carries ``prev_hash`` (the previous entry's
``entry_hash``; the first links to the index's genesis) and ``entry_hash = sha256(prev_hash +
canonical JSON of the entry without entry_hash)``, and it names the reviewed cycle's index
``row_hash`` at the time of the decision. So an edited decision (its hash), a deleted or reordered
one (the chain) and a cycle record changed after it was reviewed (the anchor) are each found by
``cellctl audit verify`` (:func:`check_ledger`), like an edited cycle row.

Why a ledger of its own and not rows of the cycle index: the index is written by the supervisor
only (the HMI opens it read-only, so the HMI cannot be the one that breaks a cycle's record), and
a cycle's row is closed and hashed when the cycle ends, while its review happens later, by
someone else (docs/decisions.md).

Appends are serialised by a lock file (``fcntl.flock``) as well as a thread lock: two HMI
processes on one records folder still write one chain.
"""

from __future__ import annotations

import datetime as _dt
import fcntl
import json
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from cellctl.errors import RecordingError
from cellctl.hashing import bytes_sha256

__all__ = ["LEDGER_FORMAT", "LEDGER_NAME", "Ledger", "LedgerProblem", "check_ledger", "entry_hash"]

LEDGER_FORMAT = "cellctl-review/1"
LEDGER_NAME = "reviews.jsonl"
"""The ledger's file name inside ``recording.dir``."""
GENESIS = "0" * 64
"""What the first entry links to (the cycle index's genesis value)."""
Kind = Literal["decision", "release"]


def entry_hash(entry: dict[str, Any]) -> str:
    """``sha256(prev_hash + canonical JSON of the entry without entry_hash)``."""
    body = {k: v for k, v in entry.items() if k != "entry_hash"}
    canon = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return bytes_sha256((str(entry.get("prev_hash", "")) + canon).encode())


@dataclass(frozen=True)
class LedgerProblem:
    """One thing :func:`check_ledger` found; ``kind`` is ``edited``, ``chain`` or ``anchor``."""

    kind: Literal["edited", "chain", "anchor", "unreadable"]
    message: str
    seq: int | None = None
    cycle_id: str | None = None


class Ledger:
    """Append and read the review ledger of one records folder.

    Args:
        path: the ledger file (``<recording.dir>/reviews.jsonl``); created on the first append.
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()

    @contextmanager
    def _locked(self) -> Iterator[None]:
        with self._lock:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with open(self.path.with_name(self.path.name + ".lock"), "a") as lk:
                fcntl.flock(lk, fcntl.LOCK_EX)
                try:
                    yield
                finally:
                    fcntl.flock(lk, fcntl.LOCK_UN)

    def entries(self) -> list[dict[str, Any]]:
        """Every entry, oldest first (an unreadable line raises: the ledger is evidence, never skipped).

        Raises:
            RecordingError: the file cannot be read or a line is not a JSON object.
        """
        if not self.path.is_file():
            return []
        out = []
        try:
            lines = self.path.read_text().splitlines()
        except OSError as err:
            raise RecordingError(f"review ledger {str(self.path)!r} cannot be read: {err.strerror}") from err
        for n, line in enumerate(lines, 1):
            try:
                e = json.loads(line)
            except ValueError:
                raise RecordingError(f"review ledger line {n} is not JSON: {line[:80]!r}") from None
            if not isinstance(e, dict):
                raise RecordingError(f"review ledger line {n} is not a JSON object: {line[:80]!r}")
            out.append(e)
        return out

    def append(self, kind: Kind, cycle_id: str, cycle_row_hash: str | None, user: str, role: str,
               **fields: Any) -> dict[str, Any]:  # fmt: skip
        """Append one entry (stamped now, UTC) and return it with its ``seq`` and hashes.

        Raises:
            RecordingError: the ledger cannot be read or written.
        """
        with self._locked():
            prev = self.entries()
            last = prev[-1] if prev else None
            entry: dict[str, Any] = {
                "format": LEDGER_FORMAT,
                "seq": (int(last["seq"]) + 1) if last else 1,
                "kind": kind,
                "cycle_id": cycle_id,
                "cycle_row_hash": cycle_row_hash,
                "user": user,
                "role": role,
                "time": _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds"),
                **fields,
                "prev_hash": last["entry_hash"] if last else GENESIS,
            }
            entry["entry_hash"] = entry_hash(entry)
            line = json.dumps(entry, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
            try:
                with self.path.open("a") as f:
                    f.write(line + "\n")
                    f.flush()
            except OSError as err:
                raise RecordingError(f"review ledger {str(self.path)!r} cannot be written: {err.strerror}") from err
        return entry

    def of_cycle(self, cycle_id: str) -> list[dict[str, Any]]:
        return [e for e in self.entries() if e.get("cycle_id") == cycle_id]

    def head(self) -> dict[str, Any]:
        """``{"entries", "seq", "entry_hash"}`` of the newest entry (the value to export, like the index head)."""
        es = self.entries()
        return {"entries": len(es), "seq": es[-1]["seq"] if es else 0, "entry_hash": es[-1]["entry_hash"] if es
                else GENESIS}  # fmt: skip


def check_ledger(path: Path, row_hashes: dict[str, str | None]) -> list[LedgerProblem]:
    """Check the ledger's hashes, its chain and its anchors in the cycle index.

    Args:
        path: the ledger file; a missing one has nothing to check.
        row_hashes: each cycle's current ``row_hash`` in the index (cycle id -> hash).
    """
    try:
        entries = Ledger(path).entries()
    except RecordingError as err:
        return [LedgerProblem("unreadable", str(err))]
    problems: list[LedgerProblem] = []
    prev_hash, prev_seq = GENESIS, 0
    for e in entries:
        seq, cid = e.get("seq"), e.get("cycle_id")
        name = f"review #{seq} ({e.get('kind')} of cycle {cid} by {e.get('user')} at {e.get('time')})"
        if e.get("entry_hash") != entry_hash(e):
            problems.append(LedgerProblem("edited", f"{name} does not hash to its entry_hash {e.get('entry_hash')}: "
                                          f"the entry was edited (computed {entry_hash(e)})", seq, cid))  # fmt: skip
        if e.get("prev_hash") != prev_hash or seq != prev_seq + 1:
            problems.append(LedgerProblem("chain", f"{name} follows #{prev_seq} but links to prev_hash "
                                          f"{e.get('prev_hash')}, expected {prev_hash}: entries were deleted or "
                                          "reordered", seq, cid))  # fmt: skip
        if cid not in row_hashes:
            problems.append(LedgerProblem("anchor", f"{name} reviews a cycle that is not in the index", seq, cid))
        elif row_hashes[cid] != e.get("cycle_row_hash"):
            problems.append(LedgerProblem("anchor", f"{name} was made on the cycle record with row_hash "
                                          f"{e.get('cycle_row_hash')}; the index now holds {row_hashes[cid]}: the "
                                          "record changed after its review", seq, cid))  # fmt: skip
        prev_hash = str(e.get("entry_hash"))
        prev_seq = seq if isinstance(seq, int) else prev_seq + 1
    return problems
