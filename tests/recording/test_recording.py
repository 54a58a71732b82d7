"""Cycle logs read back with the independent MCAP reader, also after a crash; the index chains."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader

from cellctl.messages import Status
from cellctl.recording.cycle_log import CycleLog
from cellctl.recording.foxglove import SCHEMAS
from cellctl.recording.index import CycleIndex, row_hash


def test_cycle_log_round_trip(tmp_path: Path) -> None:
    log = CycleLog(tmp_path / "c.mcap", "c1")
    log.write_message("cell/cell1/status", Status(cell="cell1", state="Idle", state_code=4, available_commands=[]))
    log.event(2, "hello")
    log.image("/camera/image", b"\x89PNG fake", "png")
    log.close({"outcome": "completed"})
    log.close()  # idempotent
    with open(tmp_path / "c.mcap", "rb") as f:
        r = make_reader(f)
        msgs = list(r.iter_messages())
        meta = {m.name: m.metadata for m in r.iter_metadata()}
    assert [s.name for s, _, _ in msgs] == ["cellctl/Status", "foxglove.Log", "foxglove.CompressedImage"]
    assert json.loads(msgs[1][2].data)["message"] == "hello"
    assert meta["cycle"]["cycle_id"] == "c1" and meta["result"]["outcome"] == "completed"
    for schema, _, _ in msgs:
        if schema.name.startswith("foxglove."):
            assert json.loads(schema.data) == SCHEMAS[schema.name]


def test_a_killed_writer_leaves_every_written_message_readable(tmp_path: Path) -> None:
    path = tmp_path / "crash.mcap"
    code = (
        "import os\nfrom cellctl.recording.cycle_log import CycleLog\n"
        f"log = CycleLog({str(path)!r}, 'c')\n"
        "for i in range(200):\n    log.event(2, f'event {i}')\n"
        "os.kill(os.getpid(), 9)\n"
    )
    p = subprocess.run([sys.executable, "-c", code], env={**os.environ})
    assert p.returncode == -9
    n = 0
    with open(path, "rb") as f:
        try:
            for rec in StreamReader(f, skip_magic=False).records:
                if isinstance(rec, Message):
                    n += 1
        except Exception:  # the missing footer ends the stream
            pass
    assert n == 200


def test_index_hash_chain_and_interrupted_rows(tmp_path: Path) -> None:
    idx = CycleIndex(tmp_path / "cells.db")
    idx.begin("a", "cell1", str(tmp_path / "a.mcap"))
    ra = idx.finish("a", "completed", verdict="clean")
    idx.begin("b", "cell1", str(tmp_path / "b.mcap"))
    (rb,) = idx.mark_interrupted()
    assert rb.outcome == "interrupted" and rb.prev_hash == ra.row_hash
    assert rb.row_hash == row_hash(ra.row_hash, rb)
    assert [r.cycle_id for r in idx.last(5)] == ["a", "b"]
    idx.close()
