"""The audit finds every kind of tampering with the cycle index and the cycle logs, and names the cycle."""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import pytest

from cellctl.cli import main
from cellctl.errors import RecordingError
from cellctl.hashing import file_sha256
from cellctl.recording.audit import FindingKind, Severity, read_head, verify_audit
from cellctl.recording.cycle_log import CycleLog
from cellctl.recording.index import GENESIS, CycleIndex, row_hash

N = 5


class Cell:
    """An index with N closed cycles, each with a real MCAP under ``logs``."""

    def __init__(self, root: Path) -> None:
        self.logs = root / "logs"
        self.db = self.logs / "cells.db"
        self.index = CycleIndex(self.db)
        for i in range(1, N + 1):
            self.add(i)

    def log_path(self, i: int) -> Path:
        return self.logs / "2024-05-01" / f"c{i}.mcap"

    def add(self, i: int, *, close: bool = True) -> None:
        path = self.log_path(i)
        log = CycleLog(path, f"c{i}", {"cell": "cell1"})
        for k in range(20):
            log.event(2, f"cycle {i} event {k}")
        self.index.begin(f"c{i}", "cell1", str(path))
        if close:
            log.close({"outcome": "completed"})
            self.index.finish(
                f"c{i}", "completed", verdict="clean", bin_type="case_study", log_sha256=file_sha256(path)
            )

    def sql(self, *statements: str) -> None:
        db = sqlite3.connect(self.db)
        with db:
            for s in statements:
                db.execute(s)
        db.close()

    def verify(self, head: str | None = None):
        return verify_audit(self.db, self.logs, head)


@pytest.fixture
def cell(tmp_path: Path) -> Cell:
    c = Cell(tmp_path)
    yield c
    c.index.close()


def kinds(report) -> dict[FindingKind, list[str | None]]:
    out: dict[FindingKind, list[str | None]] = {}
    for f in report.tampering:
        out.setdefault(f.kind, []).append(f.cycle_id)
    return out


def test_an_intact_index_passes_and_reports_its_head(cell: Cell) -> None:
    before = cell.db.read_bytes()
    report = cell.verify()
    assert report.ok and report.findings == []
    assert report.rows == N and report.logs_checked == N
    assert report.head_seq == N and report.head_hash == cell.index.get(f"c{N}").row_hash
    assert cell.db.read_bytes() == before  # read-only


def test_an_edited_field_names_the_row_and_both_hashes(cell: Cell) -> None:
    stored = cell.index.get("c3").row_hash
    cell.sql("UPDATE cycles SET verdict='dirty' WHERE cycle_id='c3'")
    report = cell.verify()
    assert kinds(report) == {FindingKind.row_edited: ["c3"]}
    (f,) = report.tampering
    assert f.seq == 3 and stored in f.message


def test_an_edited_log_hash_is_a_row_edit(cell: Cell) -> None:
    cell.sql(f"UPDATE cycles SET log_sha256='{'ab' * 32}' WHERE cycle_id='c2'")
    assert kinds(cell.verify()) == {FindingKind.row_edited: ["c2"], FindingKind.log_mismatch: ["c2"]}


def test_a_deleted_middle_row_breaks_the_chain_and_orphans_its_log(cell: Cell) -> None:
    cell.sql("DELETE FROM cycles WHERE cycle_id='c3'")
    report = cell.verify()
    assert kinds(report) == {FindingKind.row_deleted: ["c4"], FindingKind.log_orphan: [None]}
    deleted = next(f for f in report.findings if f.kind is FindingKind.row_deleted)
    assert "after seq 2" in deleted.message
    orphan = next(f for f in report.findings if f.kind is FindingKind.log_orphan)
    assert orphan.path == str(cell.log_path(3))


def test_swapped_rows_are_reported_as_reordered(cell: Cell) -> None:
    cell.sql(
        "UPDATE cycles SET seq=100 WHERE seq=2",
        "UPDATE cycles SET seq=2 WHERE seq=3",
        "UPDATE cycles SET seq=3 WHERE seq=100",
    )
    found = kinds(cell.verify())
    assert set(found) == {FindingKind.rows_reordered}
    assert {"c2", "c3"} <= set(found[FindingKind.rows_reordered])


@pytest.mark.parametrize("damage", ["flip", "truncate", "replace", "delete"])
def test_a_damaged_log_is_found_by_its_hash(cell: Cell, damage: str) -> None:
    path = cell.log_path(2)
    data = path.read_bytes()
    expected = cell.index.get("c2").log_sha256
    if damage == "flip":
        path.write_bytes(data[:300] + bytes([data[300] ^ 1]) + data[301:])
    elif damage == "truncate":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "replace":
        shutil.copy(cell.log_path(4), path)
    else:
        path.unlink()
    report = cell.verify()
    kind = FindingKind.log_missing if damage == "delete" else FindingKind.log_mismatch
    assert kinds(report) == {kind: ["c2"]}
    (f,) = report.tampering
    assert f.path == str(path) and expected in f.message
    if damage != "delete":
        assert file_sha256(path) in f.message


def test_a_log_no_row_references_is_an_orphan(cell: Cell) -> None:
    extra = cell.logs / "2024-05-02" / "stray.mcap"
    extra.parent.mkdir()
    shutil.copy(cell.log_path(1), extra)
    report = cell.verify()
    assert kinds(report) == {FindingKind.log_orphan: [None]}
    assert report.tampering[0].path == str(extra)


def test_deleting_the_newest_rows_needs_the_exported_head_to_be_certain(cell: Cell) -> None:
    head = read_head(cell.db).row_hash
    cell.index.close()
    cell.sql("DELETE FROM cycles WHERE seq >= 4")
    cell.log_path(4).unlink()
    cell.log_path(5).unlink()
    # sqlite_sequence still remembers seq 5: a hint an editor can also erase
    assert kinds(cell.verify()) == {FindingKind.tail_missing: [None]}
    cell.sql("UPDATE sqlite_sequence SET seq=3 WHERE name='cycles'")
    assert cell.verify().ok  # the documented limit: nothing left to compare with
    report = cell.verify(head)
    assert kinds(report) == {FindingKind.head_missing: [None]}
    assert head in report.tampering[0].message


def test_a_rewritten_chain_passes_alone_but_not_against_the_head(cell: Cell) -> None:
    head = read_head(cell.db).row_hash
    cell.index.close()
    cell.sql("UPDATE cycles SET verdict='dirty' WHERE cycle_id='c2'")
    db = sqlite3.connect(cell.db)
    prev = GENESIS
    for row in CycleIndex(cell.db).all():
        h = row_hash(prev, row.__class__(**{**row.__dict__, "prev_hash": prev}))
        db.execute("UPDATE cycles SET prev_hash=?, row_hash=? WHERE seq=?", (prev, h, row.seq))
        prev = h
    db.commit()
    db.close()
    assert cell.verify().ok
    assert kinds(cell.verify(head)) == {FindingKind.head_missing: [None]}


def test_an_older_head_stays_valid_as_cycles_are_added(cell: Cell) -> None:
    head = read_head(cell.db).row_hash
    cell.add(N + 1)
    assert cell.verify(head).ok
    assert cell.verify(GENESIS).ok
    with pytest.raises(RecordingError, match="64 lowercase hex"):
        cell.verify("nothex")


def test_a_running_cycle_is_info_not_tampering(cell: Cell) -> None:
    cell.add(N + 1, close=False)
    report = cell.verify()
    assert report.ok
    assert [(f.kind, f.cycle_id, f.severity) for f in report.findings] == [
        (FindingKind.running, f"c{N + 1}", Severity.info)
    ]


def test_an_interrupted_cycle_is_verified_against_its_log_as_found(cell: Cell) -> None:
    cell.add(N + 1, close=False)  # the writer "crashed": no footer
    cell.index.close()
    cell.index = CycleIndex(cell.db)
    (row,) = cell.index.mark_interrupted()
    assert row.outcome == "interrupted" and row.log_sha256 == file_sha256(cell.log_path(N + 1))
    assert cell.verify().ok
    with open(cell.log_path(N + 1), "ab") as f:
        f.write(b"appended later")
    (f,) = cell.verify().tampering
    assert f.kind is FindingKind.log_mismatch and f.cycle_id == f"c{N + 1}" and "as found" in f.message


def test_an_interrupted_cycle_without_a_log_is_info(cell: Cell) -> None:
    cell.index.begin("c9", "cell1", str(cell.logs / "never-written.mcap"))
    cell.index.mark_interrupted()
    report = cell.verify()
    assert report.ok and [f.kind for f in report.findings] == [FindingKind.no_log]
    (cell.logs / "never-written.mcap").write_bytes(b"late")
    assert kinds(cell.verify()) == {FindingKind.log_unrecorded: ["c9"]}


def test_progress_is_reported_per_row(cell: Cell) -> None:
    seen: list[tuple[int, int]] = []
    verify_audit(cell.db, cell.logs, progress=lambda done, total: seen.append((done, total)))
    assert seen == [(i, N) for i in range(1, N + 1)]


def _cli(cell: Cell, *args: str) -> int:
    return main(["audit", *args, "--set", f"recording.index={cell.db}", "--set", f"recording.dir={cell.logs}"])


def test_cli_exit_codes_and_head(cell: Cell, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert _cli(cell, "head") == 0
    head, seq = capsys.readouterr().out.split()
    assert seq == str(N) and head == cell.index.get(f"c{N}").row_hash
    assert _cli(cell, "verify") == 0
    assert "intact" in capsys.readouterr().out
    cell.log_path(1).write_bytes(b"x")
    assert _cli(cell, "verify", "--json", "--head", head) == 1
    out = json.loads(capsys.readouterr().out)
    assert not out["ok"] and [f["kind"] for f in out["findings"]] == ["log_mismatch"]
    assert out["findings"][0]["cycle_id"] == "c1"
    missing = tmp_path / "elsewhere" / "cells.db"
    assert main(["audit", "verify", "--set", f"recording.index={missing}"]) == 2
    assert str(missing) in capsys.readouterr().err
    assert _cli(cell, "verify", "--head", "zz") == 2


def test_closing_a_row_twice_is_refused_and_changes_nothing(cell: Cell) -> None:
    before = cell.index.all()
    with pytest.raises(RecordingError, match="'c3' is already closed"):
        cell.index.finish("c3", "aborted")
    with pytest.raises(RecordingError, match="'nope' is not in the index"):
        cell.index.finish("nope", "aborted")
    assert cell.index.all() == before
    assert cell.verify().ok
