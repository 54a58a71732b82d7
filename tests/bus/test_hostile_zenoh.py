"""The live daemon under a hostile Zenoh client (part of the hostile-client suite, `make test-all`; loopback only).

A real daemon (router + supervisor in this process) with worker doubles; the hostile client is a plain
Zenoh session on the cell's ``cmd`` key, sending by put and by query. Every case asserts that nothing
moved — the daemon stays Stopped, no worker is asked for anything, no cycle result — and that the
supervisor still answers a Status query. The bus here is unsecured (any client may put on ``cmd``): what
stops these commands is the supervisor's own checks (``supervisor/commands.py``, ``replay_guard.py``).
"""

from __future__ import annotations

import datetime as dt
import json
import queue
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from cellctl.app import Cell
from cellctl.bus import keys
from cellctl.bus.codec import decode_as, encode
from cellctl.bus.plc_client import PlcClient
from cellctl.bus.session import open_session
from cellctl.config import CellConfig, load_config
from cellctl.messages import Ack, Command, Status, now_iso
from cellctl.recording.replay import read_cycle
from cellctl.supervisor.replay_guard import DEDUP_WINDOW_IDS
from tests.conftest import cfg_overrides, free_port
from tests.fakes.daemon import live_daemon, record_a_cycle
from tests.fakes.workers import FakeCell

pytestmark = pytest.mark.slow

RESET = {"type": "cellctl/Command", "v": 1, "command": "reset"}
"""A command the Stopped machine accepts: any of these let through would leave Stopped."""


class Hostile:
    """A plain Zenoh client on the cell's command key (no PlcClient: nothing stamps or numbers for it)."""

    def __init__(self, cfg: CellConfig) -> None:
        self.cell = cfg.cell_id
        self.session = open_session(cfg, "client")
        self.acks: queue.Queue[Ack] = queue.Queue()
        self._sub = self.session.declare_subscriber(
            keys.cmd_ack(self.cell), lambda s: self.acks.put(decode_as(Ack, s.payload.to_bytes()))
        )
        time.sleep(0.3)  # let the subscriber's declaration reach the router

    def query(self, payload: bytes) -> Ack:
        """Send by query; the daemon's Ack (it always answers one)."""
        replies = list(self.session.get(keys.cmd(self.cell), payload=payload, timeout=15))
        assert replies and replies[0].ok is not None, f"no Ack for {payload[:80]!r}"
        return decode_as(Ack, replies[0].ok.payload.to_bytes())

    def put(self, payload: bytes) -> None:
        self.session.put(keys.cmd(self.cell), payload, congestion_control=zenoh.CongestionControl.BLOCK)

    def put_acks(self, n: int, timeout: float) -> list[Ack]:
        """The next ``n`` Acks on ``cmd/ack`` (one per put), failing after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        out = []
        while len(out) < n:
            left = deadline - time.monotonic()
            assert left > 0, f"{len(out)} of {n} Acks within {timeout:g} s"
            out.append(self.acks.get(timeout=left))
        return out

    def status(self) -> Status:
        replies = list(self.session.get(keys.status(self.cell), timeout=10))
        assert replies and replies[0].ok is not None, "the supervisor did not answer a Status query"
        return decode_as(Status, replies[0].ok.payload.to_bytes())

    def close(self) -> None:
        self._sub.undeclare()
        self.session.close()


@pytest.fixture
def live(cfg: CellConfig) -> Iterator[tuple[Cell, FakeCell, Hostile]]:
    """A Stopped daemon with every worker double alive, and a hostile client."""
    cell = live_daemon(cfg)
    with FakeCell(cfg) as fake:
        hostile = Hostile(cfg)
        try:
            yield cell, fake, hostile
        finally:
            hostile.close()
            cell.close()


def _unmoved(cell: Cell, fake: FakeCell, hostile: Hostile, results: int = 0, state: str = "Stopped") -> None:
    """Nothing moved, and the supervisor is alive and answering."""
    assert cell.supervisor.top_state == state
    assert fake.calls == []  # no worker was asked for anything: no cycle
    assert len(cell.supervisor.results) == results
    st = hostile.status()
    assert st.state == state and (results or st.cycle_id is None)


def _refused(ack: Ack, *why: str, state: str = "Stopped") -> None:
    assert not ack.accepted and ack.state == state, ack
    assert any(w in (ack.reason or "") for w in why), ack.reason


def _stamp(seconds_from_now: float) -> str:
    return (dt.datetime.now(dt.UTC) + dt.timedelta(seconds=seconds_from_now)).isoformat()


def _plc(cfg: CellConfig, *steps: tuple[str, str]) -> list[str]:
    """The PLC sends each (command, state it leads to) and waits for the state; the request ids it used."""
    with PlcClient(cfg, "plc") as plc:
        ids = []
        for name, state in steps:
            ack = plc.command(name, timeout=10)
            assert ack.accepted, ack
            ids.append(ack.request_id)
            assert plc.wait_for(lambda s, state=state: s.state == state, 30) is not None
        return ids


def _plc_ids(cfg: CellConfig) -> list[str]:
    """The PLC resets and stops the cell (back to Stopped); the request ids it used, acted on by the daemon."""
    return _plc(cfg, ("reset", "Idle"), ("stop", "Stopped"))


def _recorded_commands(log: Path, cell_id: str) -> list[bytes]:
    """The command payloads a cycle log recorded on the cell's cmd key, byte for byte."""
    recorded = [m.data for m in read_cycle(log).on(keys.cmd(cell_id))]
    cmds = [json.loads(d) for d in recorded]
    assert "start" in {c.get("command") for c in cmds}  # the Start that ran the cycle
    assert all(c.get("request_id") and c.get("stamp") for c in cmds)  # numbered and stamped, as PlcClient sends
    return recorded


def _replay_in_stopped_and_idle(
    cfg: CellConfig, cell: Cell, fake: FakeCell, hostile: Hostile, recorded: list[bytes], why: str, results: int
) -> None:
    """Put and query each recorded command three times in Stopped (where a Reset would act) and in Idle
    (where a Start would: a cycle, the arm moving); each must be refused for ``why`` where its state
    would have let it act, and nothing may move."""
    hit: set[bytes] = set()
    for state in ("Stopped", "Idle"):
        if state == "Idle":
            _plc(cfg, ("reset", "Idle"))
        fake.calls.clear()
        for data in recorded:
            for _ in range(3):
                ack = hostile.query(data)
                _refused(ack, why, "is not allowed in state", state=state)
                if why in (ack.reason or ""):
                    hit.add(data)
                hostile.put(data)
        for ack in hostile.put_acks(3 * len(recorded), 30):
            _refused(ack, why, "is not allowed in state", state=state)
        _unmoved(cell, fake, hostile, results, state)
    assert hit == set(recorded)  # each one refused for ``why`` where its state would have let it act


def test_a_cycle_s_recorded_commands_replayed_raw_onto_its_daemon_move_nothing(cfg: CellConfig, live) -> None:
    """The commands of a cycle this daemon ran, put and queried byte for byte from its log by a client that
    bypasses `cellctl replay`: each id was acted on, each copy is refused."""
    cell, fake, hostile = live
    _plc(cfg, ("reset", "Idle"), ("start", "Complete"), ("reset", "Idle"), ("stop", "Stopped"))
    log = cfg.path(cell.supervisor.results[-1].log)
    recorded = _recorded_commands(log, cfg.cell_id)
    _replay_in_stopped_and_idle(cfg, cell, fake, hostile, recorded, "already acted on", results=1)


def test_a_recorded_log_replayed_onto_a_restarted_daemon_is_refused_as_stale(
    cfg: CellConfig, live, tmp_path: Path
) -> None:
    """A daemon that never saw the recorded ids (its window empty, as after a restart): the stamps are
    older than the freshness limit. A log worth replaying is minutes to days old; this one is seconds
    old, so this daemon's limit is set to 1.5 s and the log left to age 3 s (the shipped 60 s would make
    the test wait a minute; 1.5 s still leaves the PLC's own fresh commands time to arrive)."""
    cell, fake, hostile = live
    rec_cfg = load_config(None, cfg_overrides(tmp_path / "recorded", free_port()))  # another cell's router, gone after
    recorded = _recorded_commands(record_a_cycle(rec_cfg), cfg.cell_id)
    newest = max(dt.datetime.fromisoformat(json.loads(d)["stamp"]) for d in recorded)
    time.sleep(max(0.0, 3.0 - (dt.datetime.now(dt.UTC) - newest).total_seconds()))
    cell.supervisor.replay_guard.max_age_s = 1.5
    _replay_in_stopped_and_idle(cfg, cell, fake, hostile, recorded, "s old", results=0)


def test_forged_and_duplicated_request_ids_are_refused(cfg: CellConfig, live) -> None:
    cell, fake, hostile = live
    reset_id, stop_id = _plc_ids(cfg)
    fake.calls.clear()
    # the PLC's own ids, freshly stamped, from another client (forged) or repeated by the network (duplicated)
    for rid in (reset_id, stop_id):
        forged = encode(Command(command="reset", request_id=rid, user="mallory", stamp=now_iso()))
        _refused(hostile.query(forged), "already acted on")
        for _ in range(20):
            hostile.put(forged)
    for ack in hostile.put_acks(40, 30):
        _refused(ack, "already acted on")
        assert ack.request_id in (reset_id, stop_id)
    # ids that are not ids: refused before anything else
    for rid in ("r" * 129, 7, ["plc-1"], {"id": 1}, True):
        _refused(hostile.query(json.dumps({**RESET, "request_id": rid}).encode()), "request_id")
    _unmoved(cell, fake, hostile)
    # the control: the same Reset with an id of its own is accepted
    ack = hostile.query(encode(Command(command="reset", request_id="hostile-fresh", stamp=now_iso())))
    assert ack.accepted, ack


def test_stale_future_and_malformed_stamps_are_refused(live) -> None:
    cell, fake, hostile = live
    cases = [
        (_stamp(-3600), "s old"),
        (_stamp(-120), "s old"),
        (_stamp(300), "in the future"),
        (_stamp(86400 * 365), "in the future"),
        ("0001-01-01T00:00:00+14:00", "s old"),
        ("9999-12-31T23:59:59-14:00", "in the future"),
        (dt.datetime.now().isoformat(), "no UTC offset"),  # a local time without its offset
        ("2026-12-04", "no UTC offset"),
        ("yesterday", "not an ISO-8601 time"),
        ("2026-13-45T25:61:61+00:00", "not an ISO-8601 time"),
        (1733300000, "valid string"),  # epoch seconds
    ]
    for i, (stamp, why) in enumerate(cases):
        payload = json.dumps({**RESET, "request_id": f"stamp-{i}", "stamp": stamp}).encode()
        _refused(hostile.query(payload), why)
        hostile.put(payload)
    for ack in hostile.put_acks(len(cases), 30):
        _refused(ack, "s old", "in the future", "no UTC offset", "not an ISO-8601 time", "valid string")
    _unmoved(cell, fake, hostile)
    # the control: the same Reset, stamped now, is accepted
    ack = hostile.query(json.dumps({**RESET, "request_id": "stamp-now", "stamp": now_iso()}).encode())
    assert ack.accepted, ack


def test_malformed_oversized_and_wrong_version_payloads_are_refused(cfg: CellConfig, live) -> None:
    cell, fake, hostile = live
    limit = cfg.supervisor.max_command_bytes

    def reset(**fields: object) -> bytes:
        return json.dumps({**RESET, **fields}).encode()

    deep: object = 1
    for _ in range(40):
        deep = [deep]

    cases: list[tuple[bytes, str]] = [
        (b"", "not valid JSON"),
        (b"reset", "not valid JSON"),
        (b'{"type":"cellctl/Command","v":1,"command":"reset"', "not valid JSON"),  # truncated
        (b"\xef\xbb\xbf" + reset(), "BOM"),
        (json.dumps(RESET).encode("utf-16"), "not UTF-8"),
        (b"[" * 5000 + b"]" * 5000, "deeper than"),
        (reset(params={"x": deep}), "deeper than"),
        (b'{"type":"cellctl/Command","v":1,"cntrl_cmd":' + b"9" * 5000 + b"}", "not valid JSON"),
        (b'{"type":"cellctl/Command","v":1,"cntrl_cmd":NaN}', "finite"),
        (b'{"type":"cellctl/Command","v":1,"command":"hold","command":"reset"}', "repeats key"),
        (json.dumps([RESET]).encode(), "must be a JSON object"),
        (reset(v=2), "version 2"),
        (reset(v="1"), "version '1'"),
        (reset(v=True), "version True"),
        (json.dumps({"type": "cellctl/Command", "command": "reset"}).encode(), "version None"),
        (reset(type="cellctl/Ack"), "cellctl/Ack"),
        (reset(type="cellctl/Status"), "cellctl/Status"),
        (json.dumps({"v": 1, "command": "reset"}).encode(), "got type None"),
        (reset(command="RESET"), "command: Input should be"),
        (reset(cntrl_cmd=1), "exactly one"),
        (reset(params={"seed": 1}), "takes no params"),
        (reset(extra=1), "Extra inputs are not permitted"),
        (reset(user="a\x1b[31m"), "printable"),
        (reset(pad="x" * limit), "exceeds the limit"),
        (b"{" + b" " * (4 << 20) + b"}", "exceeds the limit"),  # 4 MiB
    ]
    for payload, why in cases:
        ack = hostile.query(payload)
        assert not ack.accepted and ack.state == "Stopped", (payload[:60], ack)
        assert why.lower() in (ack.reason or "").lower(), (payload[:60], ack.reason)
        hostile.put(payload)
    for ack in hostile.put_acks(len(cases), 60):
        assert not ack.accepted and ack.state == "Stopped", ack
    assert hostile.acks.empty()  # exactly one Ack per put
    _unmoved(cell, fake, hostile)


def test_a_flood_of_commands_moves_nothing_and_evicts_no_acted_on_id(cfg: CellConfig, live) -> None:
    """More refused commands than the id window holds, as fast as one client can put them: every one gets
    its Ack, nothing moves, the PLC's acted-on ids are still refused after it (a refused command is not
    remembered, so a flood cannot push real ids out of the window), and a real command is then served."""
    cell, fake, hostile = live
    reset_id, _ = _plc_ids(cfg)
    fake.calls.clear()

    def stale(i: int) -> bytes:
        return json.dumps({**RESET, "request_id": f"f-{i}", "stamp": _stamp(-3600)}).encode()

    def future(i: int) -> bytes:
        return json.dumps({**RESET, "request_id": f"f-{i}", "stamp": _stamp(3600)}).encode()

    kinds = [
        stale,
        future,
        stale,
        future,
        stale,
        future,
        lambda i: json.dumps({**RESET, "command": "hold", "request_id": f"f-{i}"}).encode(),  # not in Stopped
        lambda i: json.dumps({**RESET, "v": 2, "request_id": f"f-{i}"}).encode(),  # wrong version
        lambda i: b"\x00" * 64,  # not JSON
    ]
    # well-formed Resets with ids of their own, refused only for their stamps: more than the window holds
    n = (DEDUP_WINDOW_IDS + 404) * len(kinds) // 6
    replayed = encode(Command(command="reset", request_id=reset_id, stamp=now_iso()))
    t0 = time.monotonic()
    for _ in range(10):  # the PLC's id first, then the flood that would push it out of a window of refused ids
        hostile.put(replayed)
    for i in range(n):
        hostile.put(kinds[i % len(kinds)](i))
    acks = hostile.put_acks(10 + n, 240)
    took = time.monotonic() - t0
    assert not any(a.accepted for a in acks)
    assert hostile.acks.empty()  # exactly one Ack per put
    _unmoved(cell, fake, hostile)
    print(f"\nflood: {10 + n} puts acked in {took:.1f} s, all refused; the daemon stayed Stopped")
    # the PLC's Reset id is still remembered; the PLC itself is still served at once
    forged = encode(Command(command="reset", request_id=reset_id, user="mallory", stamp=now_iso()))
    _refused(hostile.query(forged), "already acted on")
    with PlcClient(cfg, "plc-after") as plc:
        assert plc.command("reset", timeout=10).accepted
