"""A replayed cycle log never drives a live cell (issue 32, item 1), on loopback.

The log is a real one: a cycle run by the daemon with worker doubles. It is then replayed with
``cellctl replay`` (a process, as a user runs it) against a fresh daemon of the same cell, whose
request-id window is empty: only the replay's isolation keeps the recorded Reset and Start away.
"""

from __future__ import annotations

import datetime as dt
import queue
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cellctl.bus import keys
from cellctl.bus.codec import decode_as, encode
from cellctl.bus.security import PRINCIPALS, access_control
from cellctl.bus.session import open_session
from cellctl.config import CellConfig
from cellctl.messages import Ack, Command, Status
from cellctl.recording.replay import RecordedCycle, RecordedMessage, read_cycle, republish
from cellctl.supervisor.replay_guard import ReplayGuard
from tests.conftest import cfg_overrides
from tests.fakes.daemon import live_daemon, record_a_cycle
from tests.fakes.workers import FakeCell


def _replay(cfg_args: list[str], log: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    sets = [a for ov in cfg_args for a in ("--set", ov)]
    return subprocess.run(
        [sys.executable, "-m", "cellctl", "replay", "--rate", "50", str(log), *sets, *extra],
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_a_replayed_log_moves_nothing_on_a_live_cell(cfg: CellConfig, tmp_path: Path, port: int) -> None:
    log = record_a_cycle(cfg)
    recorded = read_cycle(log)
    assert any(m.topic == keys.cmd(cfg.cell_id) for m in recorded.messages)  # the log holds Reset and Start
    cell = live_daemon(cfg)  # a fresh daemon: nothing remembered of the recorded request ids
    watcher = open_session(cfg, "client")
    statuses: queue.Queue[Status] = queue.Queue()
    acks: queue.Queue[Ack] = queue.Queue()
    replayed: list[str] = []
    c = cfg.cell_id
    subs = [
        watcher.declare_subscriber(keys.status(c), lambda s: statuses.put(decode_as(Status, s.payload.to_bytes()))),
        watcher.declare_subscriber(keys.cmd_ack(c), lambda s: acks.put(decode_as(Ack, s.payload.to_bytes()))),
        watcher.declare_subscriber(keys.replay_all(), lambda s: replayed.append(str(s.key_expr))),
    ]
    try:
        with FakeCell(cfg) as fake:
            time.sleep(0.3)
            out = _replay(cfg_overrides(tmp_path, port), log)
            assert out.returncode == 0, out.stderr
            time.sleep(1.0)  # a Start let through would have left Stopped by now
            assert cell.supervisor.top_state == "Stopped"
            assert fake.calls == []  # no worker was asked for anything: no cycle
            assert acks.empty()  # no command reached the supervisor
            seen = []
            while not statuses.empty():
                seen.append(statuses.get_nowait())
            # the live Status is the daemon's own: no recorded Idle/Execute/Complete mixed in
            assert seen and {s.state for s in seen} == {"Stopped"} and all(s.cycle_id is None for s in seen)
            assert cell.supervisor.results == []
        # everything went under replay/<cycle>/, the recorded cycle's name
        assert replayed and all(k.startswith(keys.replay_prefix(recorded.name)) for k in replayed)
        assert f"{keys.replay_prefix(recorded.name)}{keys.cmd(c)}" in replayed
    finally:
        for s in subs:
            s.undeclare()
        watcher.close()
        cell.close()
    # --live onto the keys of a cell whose supervisor answers: refused, nothing published
    cell = live_daemon(cfg)
    try:
        time.sleep(0.3)
        out = _replay(cfg_overrides(tmp_path, port), log, "--live")
        assert out.returncode == 2
        assert "live supervisor" in out.stderr and keys.alive(c, "supervisor") in out.stderr
        # the config line, then the error in one line: no traceback
        assert "Traceback" not in out.stderr and out.stderr.splitlines()[-1].startswith("cellctl replay: error:")
        assert cell.supervisor.top_state == "Stopped"
    finally:
        cell.close()


class _Puts:
    """A session double that records puts."""

    def __init__(self) -> None:
        self.keys: list[str] = []

    def put(self, key: str, data: bytes) -> None:
        self.keys.append(key)


def _log(*topics: str) -> RecordedCycle:
    msgs = [RecordedMessage(t, "x", i, b"{}") for i, t in enumerate(topics)]
    return RecordedCycle(Path("/logs/20260101T000000-000-1.mcap"), msgs)


def test_live_mode_never_publishes_a_command_or_an_ack() -> None:
    rec = _log(keys.cmd("cell1"), keys.cmd_ack("cell1"), keys.status("cell1"), "/camera/image")
    s = _Puts()
    assert republish(rec, s, rate=1000, live=True) == 2
    assert s.keys == [keys.status("cell1"), "camera/image"]


def test_a_prefix_onto_a_cell_s_keys_is_refused_without_live() -> None:
    from cellctl.errors import RecordingError

    rec = _log(keys.cmd("cell1"), keys.status("cell1"))
    for prefix in ("", "cell/"):
        s = _Puts()
        with pytest.raises(RecordingError, match="would publish on a cell's keys"):
            republish(rec, s, rate=1000, prefix=prefix)
        assert s.keys == []
    s = _Puts()
    republish(rec, s, rate=1000)
    under = "replay/20260101T000000-000-1/"
    assert s.keys == [f"{under}{keys.cmd('cell1')}", f"{under}{keys.status('cell1')}"]


def test_the_supervisor_refuses_an_acted_on_request_id_and_a_stale_stamp(cfg: CellConfig) -> None:
    from cellctl.recording.index import CycleIndex
    from cellctl.supervisor.supervisor import Supervisor

    idx = CycleIndex(cfg.path(cfg.recording.index))
    sup = Supervisor(cfg, None, idx)  # never started: the command path alone
    try:
        assert sup.apply_command(encode(Command(command="reset", request_id="plc-1"))).accepted
        sup.machine.set_state("Stopped")
        again = sup.apply_command(encode(Command(command="reset", request_id="plc-1")))
        assert not again.accepted and "request_id 'plc-1' was already acted on" in again.reason
        assert again.request_id == "plc-1" and sup.top_state == "Stopped"
        old = (dt.datetime.now(dt.UTC) - dt.timedelta(hours=1)).isoformat()
        stale = sup.apply_command(encode(Command(command="reset", request_id="plc-2", stamp=old)))
        assert not stale.accepted and "3600 s old" in stale.reason and sup.top_state == "Stopped"
        ahead = (dt.datetime.now(dt.UTC) + dt.timedelta(minutes=5)).isoformat()
        ahead_ack = sup.apply_command(encode(Command(command="reset", request_id="p3", stamp=ahead)))
        assert "in the future" in ahead_ack.reason
        fresh = dt.datetime.now(dt.UTC).isoformat()
        assert sup.apply_command(encode(Command(command="reset", request_id="plc-4", stamp=fresh))).accepted
    finally:
        idx.close()


def test_the_request_id_window_is_bounded_in_time_and_size() -> None:
    g = ReplayGuard(window_s=10, max_ids=2)
    a, b, c = (Command(command="reset", request_id=r) for r in "abc")
    g.acted(a, now=0.0)
    assert g.refusal(a, now=5.0) is not None
    assert g.refusal(a, now=10.5) is None  # forgotten after the window
    g.acted(a, now=11)
    g.acted(b, now=12)
    g.acted(c, now=13)
    assert g.refusal(a, now=14) is None and g.refusal(c, now=14) is not None  # oldest dropped at the size bound


def test_the_replay_principal_has_no_command_grant() -> None:
    acl = access_control("cell1")
    rules = {r["id"]: r for r in acl["rules"]}
    (policy,) = [p for p in acl["policies"] if p["id"] == "replay"]
    granted = [rules[i] for i in policy["rules"]]
    ingress_keys = {k for r in granted if r["flows"] == ["ingress"] and "put" in r["messages"] for k in r["key_exprs"]}
    assert ingress_keys == {keys.replay_all()}
    assert "command" not in PRINCIPALS["replay"].grants
    assert not any(keys.cmd("cell1") in r["key_exprs"] for r in granted)
