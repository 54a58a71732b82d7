"""A cycle log cut short at any byte is recovered into a file the standard indexed reader reads,
holding exactly the complete messages before the cut; the original is never touched."""

from __future__ import annotations

import hashlib
import json
import shutil
import sqlite3
import struct
from pathlib import Path

import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from cellctl.cli import main
from cellctl.errors import RecordingError
from cellctl.hashing import file_sha256
from cellctl.messages import Status
from cellctl.recording.audit import FindingKind, checked_log, find_cycle, verify_audit
from cellctl.recording.cycle_log import CycleLog
from cellctl.recording.index import GENESIS, CycleIndex, CycleRow, row_hash
from cellctl.recording.recover import recover_mcap, recovered_path
from cellctl.recording.replay import read_cycle

MAGIC = 8
HEAD = struct.Struct("<BQ")
MESSAGE, CHUNK, FOOTER, DATA_END = 0x05, 0x06, 0x02, 0x0F

# One message of each kind a cycle writes; the image is large enough that a cut inside it is
# clearly "mid-record".
IMAGE = bytes(range(256)) * 2000


def _write_cycle_log(path: Path, *, close: bool = True) -> CycleLog:
    log = CycleLog(path, "c1", {"cell": "cell1"})
    for i in range(5):
        log.write_message(
            "cell/cell1/status",
            Status(cell="cell1", state="Execute", state_code=6, step="scanning", available_commands=[]),
            t_ns=1_000 + 3 * i,
        )
        log.event(2, f"viewpoint {i}", t_ns=1_001 + 3 * i)
        log.image("/camera/image", IMAGE[: 10_000 * (i + 1)], "png", t_ns=1_002 + 3 * i)
    if close:
        log.close({"outcome": "completed"})
    return log


def _streamed(path: Path) -> list[tuple[str, str, int, int, int, bytes]]:
    """Every message of a whole file, by the library's streaming reader (the reference)."""
    schemas, channels, out = {}, {}, []
    with open(path, "rb") as f:
        for rec in StreamReader(f, skip_magic=False).records:
            if type(rec).__name__ == "Schema":
                schemas[rec.id] = rec.name
            elif type(rec).__name__ == "Channel":
                channels[rec.id] = (rec.topic, rec.schema_id)
            elif isinstance(rec, Message):
                topic, sid = channels[rec.channel_id]
                out.append((topic, schemas.get(sid, ""), rec.log_time, rec.publish_time, rec.sequence, bytes(rec.data)))
    return out


def _message_ends(data: bytes) -> list[int]:
    """File offset where each message record ends, in file order (inner records of uncompressed chunks too).

    An independent walk of the record framing (opcode u8, length u64), not the code under test.
    """
    ends, pos = [], MAGIC
    while pos + HEAD.size <= len(data):
        op, length = HEAD.unpack_from(data, pos)
        body = pos + HEAD.size
        if op == MESSAGE:
            ends.append(body + length)
        elif op == CHUNK:
            name_len = struct.unpack_from("<I", data, body + 28)[0]
            assert data[body + 32 : body + 32 + name_len] == b"", "only uncompressed chunks have file offsets"
            inner = body + 32 + name_len + 8
            stop = body + length
            while inner < stop:
                iop, ilen = HEAD.unpack_from(data, inner)
                if iop == MESSAGE:
                    ends.append(inner + HEAD.size + ilen)
                inner += HEAD.size + ilen
        elif op == FOOTER:
            break
        pos = body + length
    return ends


def _record_starts(data: bytes, opcode: int) -> list[int]:
    out, pos = [], MAGIC
    while pos + HEAD.size <= len(data):
        op, length = HEAD.unpack_from(data, pos)
        if op == opcode:
            out.append(pos)
        if op == FOOTER:
            break
        pos += HEAD.size + length
    return out


def _read_indexed(path: Path):
    """What the standard indexed entry point reads: (summary, messages, metadata by name)."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        msgs = [
            (ch.topic, sc.name if sc else "", m.log_time, m.publish_time, m.sequence, bytes(m.data))
            for sc, ch, m in reader.iter_messages()
        ]
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return summary, msgs, meta


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def full_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("log") / "c1.mcap"
    _write_cycle_log(path)
    return path


def _cut_points(data: bytes) -> dict[str, int]:
    ends = _message_ends(data)
    image = _record_starts(data, MESSAGE)[2]  # the first image message
    image_end = ends[2]
    return {
        "empty": 0,
        "inside the magic": 5,
        "after the magic": MAGIC,
        "inside the header record's framing": MAGIC + 4,
        "inside the header record": MAGIC + 15,
        "between records": ends[4],
        "mid-record (inside an image)": (image + image_end) // 2,
        "mid-record (inside a record header)": ends[6] + 3,
        "one byte short of a message": ends[9] - 1,
        "after the last message": ends[-1],
        "just before the footer": _record_starts(data, FOOTER)[0],
        "inside the footer": _record_starts(data, FOOTER)[0] + 10,
        "just before the closing magic": len(data) - MAGIC,
    }


# Cuts on a record boundary: every byte before them belongs to a complete record.
EXACT = {"empty", "after the magic", "between records", "after the last message", "just before the footer"}
EXACT |= {"just before the closing magic"}


@pytest.mark.parametrize(
    "where",
    [
        "empty",
        "inside the magic",
        "after the magic",
        "inside the header record's framing",
        "inside the header record",
        "between records",
        "mid-record (inside an image)",
        "mid-record (inside a record header)",
        "one byte short of a message",
        "after the last message",
        "just before the footer",
        "inside the footer",
        "just before the closing magic",
    ],
)
def test_a_cycle_log_cut_anywhere_recovers_to_exactly_its_complete_messages(
    full_log: Path, tmp_path: Path, where: str
) -> None:
    data = full_log.read_bytes()
    cut = _cut_points(data)[where]
    reference = _streamed(full_log)
    ends = _message_ends(data)
    assert len(ends) == len(reference) == 15
    expected = [m for m, end in zip(reference, ends, strict=True) if end <= cut]

    src = tmp_path / "c1.mcap"
    src.write_bytes(data[:cut])
    before = _sha(src)
    if cut >= 40:  # past the header: the defect itself, the indexed reader refuses the cut file
        with open(src, "rb") as f, pytest.raises(McapError):  # RecordLengthLimitExceeded or EndOfFile
            reader = make_reader(f)
            reader.get_summary()
            list(reader.iter_messages())

    found = recover_mcap(src)

    assert Path(found.out) == tmp_path / "c1.recovered.mcap" == recovered_path(src)
    summary, msgs, meta = _read_indexed(Path(found.out))
    assert msgs == expected
    assert found.messages == len(expected)
    assert summary is not None and summary.statistics.message_count == len(expected)
    if expected:
        assert summary.chunk_indexes, "the recovered file is indexed"
    assert _sha(src) == before == found.source_sha256 and src.stat().st_size == cut == found.source_bytes
    assert found.out_sha256 == _sha(Path(found.out))
    assert found.intact_bytes <= cut and (found.intact_bytes == cut) == (where in EXACT)
    assert not found.had_footer and found.stopped
    assert meta["recovery"]["intact_bytes"] == str(found.intact_bytes)
    if cut > 100:  # the cycle metadata record follows the header
        assert meta["cycle"] == {"cycle_id": "c1", "cell": "cell1"}
    if cut >= _record_starts(data, FOOTER)[0]:
        assert meta["result"] == {"outcome": "completed"}


def test_a_complete_log_recovers_to_the_same_messages_and_says_it_was_complete(full_log: Path, tmp_path: Path) -> None:
    found = recover_mcap(full_log, tmp_path / "copy.mcap")
    assert found.had_footer and found.stopped is None and found.intact_bytes == full_log.stat().st_size
    _, msgs, meta = _read_indexed(tmp_path / "copy.mcap")
    assert msgs == _streamed(full_log)
    assert meta["result"] == {"outcome": "completed"}


def test_recovery_is_deterministic(full_log: Path, tmp_path: Path) -> None:
    src = tmp_path / "c.mcap"
    src.write_bytes(full_log.read_bytes()[: full_log.stat().st_size // 2])
    a = recover_mcap(src, tmp_path / "a.mcap")
    b = recover_mcap(src, tmp_path / "b.mcap")
    assert a.out_sha256 == b.out_sha256


def _chunked(path: Path, compression: CompressionType, chunk_size: int = 4_000) -> None:
    """A log from elsewhere: chunked (the default of mcap writers), with an attachment and metadata."""
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=chunk_size, compression=compression)
        w.start(profile="x", library="other-recorder")
        sid = w.register_schema("foxglove.Log", "jsonschema", b'{"type":"object"}')
        cid = w.register_channel("/events", "json", sid)
        raw = w.register_channel("/raw", "application/octet-stream", 0)  # a channel without a schema
        w.add_metadata("setup", {"k": "v"})
        w.add_attachment(5, 6, "calibration.yaml", "text/yaml", b"fx: 910\n")
        for i in range(300):
            # ~1 kB of poorly compressible text: a compressed chunk spans several compression blocks
            body = json.dumps({"i": i, "pad": hashlib.sha512(str(i).encode()).hexdigest() * 8}).encode()
            w.add_message(cid if i % 3 else raw, log_time=i, publish_time=i, data=body, sequence=i)
        w.finish()


def test_a_chunked_log_cut_mid_chunk_keeps_the_complete_messages_of_the_cut_chunk(tmp_path: Path) -> None:
    full = tmp_path / "full.mcap"
    _chunked(full, CompressionType.NONE)
    data = full.read_bytes()
    chunks = _record_starts(data, CHUNK)
    assert len(chunks) >= 3
    ends = _message_ends(data)
    reference = _streamed(full)
    for cut in (
        chunks[1] + 5,
        (chunks[1] + chunks[2]) // 2,
        ends[150] - 1,
        ends[150],
        _record_starts(data, DATA_END)[0],
    ):
        src = tmp_path / f"cut{cut}.mcap"
        src.write_bytes(data[:cut])
        found = recover_mcap(src)
        _, msgs, meta = _read_indexed(Path(found.out))
        expected = [m for m, end in zip(reference, ends, strict=True) if end <= cut]
        assert msgs == expected, cut
        cut_chunk = [c for c in chunks if c < cut < c + HEAD.size + HEAD.unpack_from(data, c)[1]]
        in_cut_chunk = [e for e in ends if cut_chunk and cut_chunk[0] < e <= cut]
        assert found.from_cut_chunk == len(in_cut_chunk)
        if cut == (chunks[1] + chunks[2]) // 2:  # mid-chunk: some of its messages are whole
            assert in_cut_chunk
        assert meta["setup"] == {"k": "v"} and found.attachments == 1
        with open(found.out, "rb") as f:
            (att,) = make_reader(f).iter_attachments()
        assert att.name == "calibration.yaml" and att.data == b"fx: 910\n"


@pytest.mark.parametrize("compression", [CompressionType.ZSTD, CompressionType.LZ4])
def test_a_compressed_chunk_cut_keeps_what_its_prefix_decodes(tmp_path: Path, compression: CompressionType) -> None:
    full = tmp_path / "full.mcap"
    _chunked(full, compression, chunk_size=1 << 20)  # one chunk of all 300 messages
    data = full.read_bytes()
    chunks = _record_starts(data, CHUNK)
    reference = _streamed(full)
    src = tmp_path / "cut.mcap"
    (chunk,) = chunks
    src.write_bytes(data[: chunk + HEAD.unpack_from(data, chunk)[1] // 2])
    found = recover_mcap(src)
    _, msgs, _ = _read_indexed(Path(found.out))
    # a prefix of the reference: what the compressed half of the chunk decodes to, block by block
    assert msgs == reference[: len(msgs)]
    assert found.messages == found.from_cut_chunk == len(msgs)
    assert 0 < len(msgs) < len(reference)


def test_garbage_in_the_middle_stops_recovery_there(full_log: Path, tmp_path: Path) -> None:
    data = bytearray(full_log.read_bytes())
    ends = _message_ends(bytes(data))
    data[ends[7] : ends[7] + 9] = b"\x00" * 9  # opcode 0: not a record
    src = tmp_path / "g.mcap"
    src.write_bytes(bytes(data))
    found = recover_mcap(src)
    _, msgs, _ = _read_indexed(Path(found.out))
    assert msgs == _streamed(full_log)[:8]
    assert found.intact_bytes == ends[7] and "garbage" in found.stopped


def test_a_file_that_is_not_mcap_is_refused_and_left_alone(tmp_path: Path) -> None:
    src = tmp_path / "notes.mcap"
    src.write_bytes(b"hello, not a log")
    with pytest.raises(RecordingError, match=r"notes\.mcap.*is not an MCAP file.*hello"):
        recover_mcap(src)
    assert not recovered_path(src).exists() and src.read_bytes() == b"hello, not a log"
    (tmp_path / "x.mcap").write_bytes(b"")
    with pytest.raises(RecordingError, match="is the source itself"):
        recover_mcap(tmp_path / "x.mcap", tmp_path / "x.mcap")


def test_cli_recover_writes_the_copy_and_prints_what_it_found(full_log: Path, tmp_path: Path, capsys) -> None:
    src = tmp_path / "elsewhere.mcap"
    src.write_bytes(full_log.read_bytes()[:-100])
    assert main(["recover", str(src), "--out", str(tmp_path / "fixed.mcap")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["out"] == str(tmp_path / "fixed.mcap") and out["messages"] == 15 and not out["had_footer"]
    assert _read_indexed(tmp_path / "fixed.mcap")[1] == _streamed(full_log)
    (tmp_path / "junk").write_bytes(b"junk")
    assert main(["recover", str(tmp_path / "junk")]) == 2
    assert "is not an MCAP file" in capsys.readouterr().err


# --- the index and the audit ------------------------------------------------------------------


class Logs:
    """An index with a completed cycle and one whose writer died mid-image (no footer)."""

    def __init__(self, root: Path) -> None:
        self.root = root / "logs"
        self.db = self.root / "cells.db"
        self.index = CycleIndex(self.db)
        done = self.root / "c0.mcap"
        _write_cycle_log(done)
        self.index.begin("c0", "cell1", str(done))
        self.index.finish("c0", "completed", log_sha256=file_sha256(done))
        self.cut = self.root / "c1.mcap"
        _write_cycle_log(self.cut)
        data = self.cut.read_bytes()
        self.cut_at = (_record_starts(data, MESSAGE)[8] + _message_ends(data)[8]) // 2  # inside the 3rd image
        reference = _streamed(self.cut)
        self.cut.write_bytes(data[: self.cut_at])
        self.expected = [m for m, e in zip(reference, _message_ends(data), strict=True) if e <= self.cut_at]
        self.index.begin("c1", "cell1", str(self.cut))


@pytest.fixture
def logs(tmp_path: Path) -> Logs:
    lg = Logs(tmp_path)
    yield lg
    lg.index.close()


def test_restart_recovers_the_interrupted_log_and_chains_both_hashes(logs: Logs) -> None:
    sha_as_found = file_sha256(logs.cut)
    (row,) = logs.index.mark_interrupted()
    rec = recovered_path(logs.cut)
    assert row.outcome == "interrupted" and row.row_format == 2
    assert row.log_path == str(logs.cut) and row.log_sha256 == sha_as_found == file_sha256(logs.cut)
    assert row.recovered_path == str(rec) and row.recovered_sha256 == file_sha256(rec)
    assert row.recovered_messages == len(logs.expected) == 8
    assert row.log_bytes == logs.cut_at and row.log_intact_bytes < logs.cut_at
    assert f"byte {row.log_intact_bytes}" in row.reason and "8 messages recovered" in row.reason
    assert _read_indexed(rec)[1] == logs.expected
    assert row.row_hash == row_hash(row.prev_hash, row)
    report = verify_audit(logs.db, logs.root)
    assert report.ok and report.findings == [] and report.logs_checked == 3
    assert checked_log(row) == rec
    assert find_cycle(logs.db, log=logs.cut) == row == find_cycle(logs.db, log=rec)


@pytest.mark.parametrize("damage", ["edit", "delete"])
def test_a_changed_recovered_log_is_found_and_refused(logs: Logs, damage: str) -> None:
    (row,) = logs.index.mark_interrupted()
    rec = Path(row.recovered_path)
    if damage == "edit":
        rec.write_bytes(rec.read_bytes()[:-1] + b"\x00")
    else:
        rec.unlink()
    (f,) = verify_audit(logs.db, logs.root).tampering
    want = FindingKind.recovered_mismatch if damage == "edit" else FindingKind.recovered_missing
    assert f.kind is want and f.cycle_id == "c1" and row.recovered_sha256 in f.message
    with pytest.raises(RecordingError, match=f"refusing to read cycle c1.*{row.recovered_sha256}"):
        checked_log(row)


def test_the_original_stays_evidence_and_its_hash_is_checked_too(logs: Logs) -> None:
    (row,) = logs.index.mark_interrupted()
    with open(logs.cut, "ab") as f:
        f.write(b"more")
    (f,) = verify_audit(logs.db, logs.root).tampering
    assert f.kind is FindingKind.log_mismatch and "as found" in f.message
    with pytest.raises(RecordingError, match="refusing to read cycle c1"):
        checked_log(row)


def test_editing_a_recovery_field_breaks_the_row_hash(logs: Logs) -> None:
    logs.index.mark_interrupted()
    db = sqlite3.connect(logs.db)
    with db:
        db.execute("UPDATE cycles SET recovered_messages=99 WHERE cycle_id='c1'")
    db.close()
    (f,) = verify_audit(logs.db, logs.root).tampering
    assert f.kind is FindingKind.row_edited and f.cycle_id == "c1"


def test_a_log_that_cannot_be_recovered_is_still_closed_with_its_hash(logs: Logs) -> None:
    logs.cut.write_bytes(b"not mcap at all")
    (row,) = logs.index.mark_interrupted()
    assert row.recovered_path is None and row.log_sha256 == file_sha256(logs.cut)
    assert "could not be recovered" in row.reason and "not an MCAP file" in row.reason
    assert verify_audit(logs.db, logs.root).ok


_V1_SCHEMA = """
CREATE TABLE cycles (
    seq INTEGER PRIMARY KEY AUTOINCREMENT, cycle_id TEXT UNIQUE NOT NULL, cell TEXT NOT NULL,
    started TEXT NOT NULL, finished TEXT, outcome TEXT, verdict TEXT, bin_type TEXT, plan_id TEXT,
    reason TEXT, log_path TEXT NOT NULL, log_sha256 TEXT, prev_hash TEXT, row_hash TEXT
);
"""
_V1_FIELDS = ("cycle_id", "cell", "started", "finished", "outcome", "verdict", "bin_type", "plan_id", "reason")


def _v1_row_hash(prev: str, values: dict[str, object]) -> str:
    """The row hash exactly as cellctl computed it before row format 2 (spelt out, not imported)."""
    body = json.dumps(values, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256((prev + body).encode()).hexdigest()


def test_an_index_written_before_row_format_2_still_verifies_and_grows(tmp_path: Path) -> None:
    root = tmp_path / "logs"
    root.mkdir()
    db_path = root / "cells.db"
    db = sqlite3.connect(db_path)
    db.executescript(_V1_SCHEMA)
    prev = GENESIS
    for i in range(3):
        log = root / f"old{i}.mcap"
        _write_cycle_log(log)
        values = dict(
            zip(_V1_FIELDS, (f"old{i}", "cell1", "t0", "t1", "completed", "clean", "tote", "p", None), strict=True)
        )
        values |= {"log_path": str(log), "log_sha256": file_sha256(log)}
        h = _v1_row_hash(prev, values)
        db.execute(
            "INSERT INTO cycles (cycle_id, cell, started, finished, outcome, verdict, bin_type, plan_id, reason,"
            " log_path, log_sha256, prev_hash, row_hash) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?)",
            (*values.values(), prev, h),
        )
        prev = h
    db.commit()
    db.close()
    assert verify_audit(db_path, root).ok  # read-only: the old columns only

    index = CycleIndex(db_path)  # opening adds the format-2 columns
    try:
        old = index.get("old2")
        assert isinstance(old, CycleRow) and old.row_format is None and old.row_hash == prev
        cut = root / "new.mcap"
        _write_cycle_log(cut)
        cut.write_bytes(cut.read_bytes()[:-500])
        index.begin("new", "cell1", str(cut))
        (row,) = index.mark_interrupted()
        assert row.prev_hash == prev and row.row_format == 2 and row.recovered_messages == 15
        report = verify_audit(db_path, root)
        assert report.ok and report.findings == [], report.findings
        assert read_cycle(checked_log(row)).metadata["recovery"]["source"] == "new.mcap"
    finally:
        index.close()


def test_report_reads_the_recovered_log_of_an_interrupted_cycle(logs: Logs, capsys) -> None:
    logs.index.mark_interrupted()
    sets = ["--set", f"recording.index={logs.db}", "--set", f"recording.dir={logs.root}"]
    assert main(["report", "c1", *sets]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["outcome"] == "interrupted" and out["messages"] == 8 and out["images"] == 2
    assert out["recovered_log"] == str(recovered_path(logs.cut)) and out["last_state"] == "Execute.scanning"
    shutil.copy(logs.root / "c0.mcap", recovered_path(logs.cut))  # replaced: refused
    assert main(["report", "c1", *sets]) == 2
    assert "refusing to read cycle c1" in capsys.readouterr().err


def test_replay_refuses_an_interrupted_cycle_whose_recovered_log_changed(logs: Logs, capsys) -> None:
    (row,) = logs.index.mark_interrupted()
    rec = Path(row.recovered_path)
    rec.write_bytes(rec.read_bytes() + b"x")
    sets = ["--set", f"recording.index={logs.db}", "--set", f"recording.dir={logs.root}"]
    for args in (["replay", str(logs.cut)], ["replay", str(rec)], ["replay", "--verify", str(logs.cut)]):
        assert main([*args, *sets]) == 2, args  # refused before any bus is opened
        err = capsys.readouterr().err
        assert "refusing to read cycle c1" in err and row.recovered_sha256 in err
