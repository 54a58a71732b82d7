"""The daemon SIGKILLed mid-cycle, then restarted: the cycle is marked interrupted, its cut-short log is
recovered into a valid indexed MCAP beside it (the original kept as evidence), nothing else changes."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader

from cellctl.bus import keys
from cellctl.cli import main
from cellctl.config import load_config
from cellctl.errors import ConfigError
from cellctl.hashing import file_sha256
from cellctl.recording.audit import find_cycle, verify_audit
from cellctl.recording.recover import recovered_path
from cellctl.recording.replay import read_cycle, verify
from tests.conftest import cfg_overrides, free_port
from tests.fakes.workers import FakeCell, fake_identify
from tests.supervisor.test_cycle_over_zenoh import Plc

REPO = Path(__file__).resolve().parents[2]


class Daemon:
    """``cellctl run`` (with the identification double) as a child process."""

    def __init__(self, overrides: list[str], stderr: Path) -> None:
        args = [a for ov in overrides for a in ("--set", ov)]
        self._err = open(stderr, "ab")  # closed in stop()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tests.fakes.daemon", "run", *args],
            cwd=REPO,
            stdin=subprocess.DEVNULL,
            stdout=self._err,
            stderr=self._err,
            env={**os.environ, "PYTHONPATH": str(REPO)},
        )

    def connect(self, cfg, timeout: float = 30.0) -> Plc:
        """A PLC client, once the supervisor publishes Status (its router listens a bit earlier)."""
        deadline = time.monotonic() + timeout
        while True:
            assert self.proc.poll() is None, f"daemon exited with {self.proc.returncode}"
            try:
                plc = Plc(cfg)
                break
            except ConfigError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        st = plc.status.get(timeout=max(1.0, deadline - time.monotonic()))
        plc.status.put(st)  # the caller may wait for this very state
        return plc

    def kill(self) -> None:
        self.proc.send_signal(signal.SIGKILL)
        assert self.proc.wait(10) == -signal.SIGKILL

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._err.close()


def _rows(db: Path) -> dict[str, tuple]:
    con = sqlite3.connect(f"{db.as_uri()}?mode=ro", uri=True)
    try:
        return {r[1]: r for r in con.execute("SELECT * FROM cycles ORDER BY seq")}
    finally:
        con.close()


def _stream(path: Path) -> list[tuple[str, str, dict]]:
    """(topic, schema, message) of every message a streaming reader gets before the file ends."""
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, int]] = {}
    out = []
    with open(path, "rb") as f:
        try:
            for rec in StreamReader(f, skip_magic=False).records:
                if type(rec).__name__ == "Schema":
                    schemas[rec.id] = rec.name
                elif type(rec).__name__ == "Channel":
                    channels[rec.id] = (rec.topic, rec.schema_id)
                elif isinstance(rec, Message):
                    topic, sid = channels[rec.channel_id]
                    out.append((topic, schemas[sid], json.loads(rec.data)))
        except Exception:  # a killed writer leaves no footer; the stream ends there
            pass
    return out


def _run_cycle(plc: Plc) -> None:
    assert plc.cmd("reset").accepted
    plc.wait_state("Idle")
    assert plc.cmd("start").accepted
    plc.wait_state("Complete", timeout=20)


def test_sigkill_mid_cycle_then_restart_comes_up_stopped_with_the_cycle_interrupted(tmp_path: Path, port: int) -> None:
    overrides = cfg_overrides(tmp_path, port)
    cfg = load_config(None, overrides)
    db, logs = tmp_path / "logs" / "cells.db", tmp_path / "logs"
    daemon = Daemon(overrides, tmp_path / "daemon.log")
    plc = fake = None
    try:
        plc = daemon.connect(cfg)
        fake = FakeCell(cfg, n_viewpoints=3).start()
        # a complete cycle first: its record must survive the crash unchanged
        _run_cycle(plc)
        first = plc.results.get(timeout=5)
        assert first.outcome == "completed"
        row_first = _rows(db)[first.cycle_id]
        sha_first = file_sha256(cfg.path(first.log))

        # a slow second cycle, killed while scanning
        fake.n_viewpoints, fake.move_delay_s = 20, 0.4
        moves_before = fake.calls.count("move")
        assert plc.cmd("reset").accepted
        plc.wait_state("Idle")
        assert plc.cmd("start").accepted
        deadline = time.monotonic() + 20
        while fake.calls.count("move") < moves_before + 3 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert fake.calls.count("move") >= moves_before + 3, "the second cycle did not reach scanning"
        daemon.kill()
        plc.close()
        fake.close()
        plc = fake = None

        (second,) = [r for cid, r in _rows(db).items() if cid != first.cycle_id]
        second_id, second_log = second[1], Path(second[10])
        assert second[5] is None  # outcome: still running when the supervisor died
        msgs = _stream(second_log)
        cmds = [m for t, s, m in msgs if s == "cellctl/Command"]
        assert cmds and cmds[0]["command"] == "start"
        assert any(s == "cellctl/Status" and m.get("step") == "scanning" for _, s, m in msgs)
        assert any(t == f"{keys.robot_op(cfg.cell_id, 'move')}/request" for t, _, _ in msgs)
        assert any(s == "foxglove.CompressedImage" for _, s, _ in msgs)
        assert not any(s == "cellctl/CycleResult" for _, s, _ in msgs)
        sha_as_found = file_sha256(second_log)

        daemon = Daemon(overrides, tmp_path / "daemon.log")
        plc = daemon.connect(cfg)
        st = plc.wait_state("Stopped")
        assert st.last_error is not None and second_id in st.last_error and "interrupted" in st.last_error
        rows = _rows(db)
        assert rows[first.cycle_id] == row_first
        assert file_sha256(cfg.path(first.log)) == sha_first
        assert rows[second_id][5] == "interrupted"
        assert rows[second_id][11] == sha_as_found  # log_sha256 of the file as the crash left it
        assert file_sha256(second_log) == sha_as_found
        report = verify_audit(db, logs)
        assert report.ok and report.findings == [], report.findings

        # the cut-short log, which the indexed reader refuses, was recovered beside it
        with open(second_log, "rb") as f, pytest.raises(McapError):  # RecordLengthLimitExceeded or EndOfFile
            make_reader(f).get_summary()
        row = find_cycle(db, cycle_id=second_id)
        recovered = recovered_path(second_log)
        assert row.recovered_path == str(recovered) and row.recovered_sha256 == file_sha256(recovered)
        assert row.log_bytes == second_log.stat().st_size and row.log_intact_bytes <= row.log_bytes
        with open(recovered, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            indexed = [(ch.topic, sc.name, json.loads(m.data)) for sc, ch, m in reader.iter_messages()]
        assert summary is not None and summary.chunk_indexes
        assert sorted(indexed, key=repr) == sorted(msgs, key=repr)  # every message the crash left
        assert row.recovered_messages == len(msgs) == summary.statistics.message_count
        sets = [a for ov in overrides for a in ("--set", ov)]
        assert main(["audit", "verify", *sets]) == 0

        # the cell recovers: Reset clears the error, the next cycle runs to the end
        fake = FakeCell(cfg, n_viewpoints=3).start()
        _run_cycle(plc)
        third = plc.results.get(timeout=5)
        assert third.outcome == "completed"
        rows = _rows(db)
        assert list(rows) == [first.cycle_id, second_id, third.cycle_id]
        assert rows[first.cycle_id] == row_first
        assert verify_audit(db, logs).ok
        assert main(["audit", "verify", *sets]) == 0

        # replay reads the recovered copy of the interrupted cycle's log (both hashes checked) ...
        assert main(["replay", str(second_log), "--rate", "1000", "--prefix", "replay/", *sets]) == 0
        # ... and a fresh supervisor, answered from it, makes the same requests up to the cut
        port = free_port()
        ep = f'["tcp/127.0.0.1:{port}"]'
        vcfg = load_config(
            None,
            [f"bus.listen={ep}", f"bus.connect={ep}", f"recording.dir={tmp_path / 'v'}",
             f"recording.index={tmp_path / 'v' / 'cells.db'}", f"planner.plans_dir={tmp_path / 'plans'}",
             "robot.settle_s=0"],
        )  # fmt: skip
        from cellctl.geometry.catalog import load_catalog

        result = verify(
            recovered, vcfg, timeout_s=30, identification=(fake_identify, load_catalog(cfg.path(cfg.catalog)))
        )
        assert result.interrupted and result.ok, result.differences
        # the check can fail: a supervisor with another settle time asks for other moves before the cut
        vcfg.robot.settle_s = 0.5
        changed = verify(
            recovered, vcfg, timeout_s=30, identification=(fake_identify, load_catalog(cfg.path(cfg.catalog)))
        )
        assert not changed.ok
        assert any("request on cell/cell1/robot/move differs" in d for d in changed.differences), changed.differences
        assert result.requests == sum(1 for t, _, _ in msgs if t.endswith("/request"))
        assert "Execute.scanning" in result.states_recorded
        assert read_cycle(recovered).metadata["recovery"]["source"] == second_log.name
    finally:
        for c in (plc, fake):
            if c is not None:
                c.close()
        daemon.stop()


@pytest.fixture(autouse=True)
def _daemon_log_in_the_report(tmp_path: Path):
    # pytest shows captured teardown output only for a failed test: the daemon's side of it.
    yield
    log = tmp_path / "daemon.log"
    if log.exists():
        sys.stderr.write(log.read_text(errors="replace")[-4000:])
