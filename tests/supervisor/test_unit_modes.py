"""PackML unit modes (TR88): changed only in Stopped, Idle, Aborted; manual offers no Start; both
contracts see the mode; Admin counters count inspected and dirty bins and survive a restart."""

from __future__ import annotations

import json
import time

import pytest
from mcap.reader import make_reader

from cellctl.app import build_cell
from cellctl.bus.codec import encode
from cellctl.bus.plc_client import PlcClient
from cellctl.geometry.catalog import load_catalog
from cellctl.messages import Command, UnitMode
from cellctl.recording.index import CycleIndex
from cellctl.supervisor.supervisor import Supervisor
from tests.fakes.workers import FakeCell, fake_identify
from tests.supervisor.test_packml_table import STATES

CHANGE_IN = {"Stopped", "Idle", "Aborted"}  # written here independently of unit_modes.py


@pytest.fixture
def sup(cfg):
    idx = CycleIndex(cfg.path(cfg.recording.index))
    s = Supervisor(cfg, None, idx)  # never started: the rules alone
    yield s
    idx.close()


def _set(sup: Supervisor, state: str) -> str:
    target = f"Execute.{sup.cycle.initial}" if state == "Execute" else state
    sup.machine.set_state(target)
    return target


@pytest.mark.parametrize("state", STATES)
@pytest.mark.parametrize("mode", list(UnitMode))
@pytest.mark.parametrize("by_code", [False, True])
def test_mode_change_rules_in_every_state(sup, state: str, mode: UnitMode, by_code: bool) -> None:
    target = _set(sup, state)
    before = sup.unit_mode = UnitMode.maintenance if mode == UnitMode.production else UnitMode.production
    cmd = Command(unit_mode_code=mode.value) if by_code else Command(unit_mode=mode.name)
    ack = sup.apply_command(encode(cmd.model_copy(update={"request_id": "m1", "user": "hmi:alice"})))
    assert sup.state == target, "a mode change never changes the PackML state"
    assert ack.request_id == "m1" and ack.user == "hmi:alice" and ack.state == state
    if state in CHANGE_IN:
        assert ack.accepted, ack.reason
        assert sup.unit_mode == mode and ack.unit_mode == mode.name
        st = sup.status
        assert (st.unit_mode, st.unit_mode_code) == (mode.name, mode.value)
    else:
        assert not ack.accepted
        assert (
            ack.reason == f"unit mode change to {mode.name!r} not allowed in {state}; allowed in Stopped, Idle, Aborted"
        )
        assert sup.unit_mode == before and ack.unit_mode == before.name


@pytest.mark.parametrize("state", STATES)
def test_manual_mode_offers_every_command_of_the_state_but_start(sup, state: str) -> None:
    _set(sup, state)
    table = sup.packml.allowed_commands(state)
    sup.unit_mode = UnitMode.manual
    assert sup._make_status().available_commands == [c for c in table if c != "start"]
    sup.unit_mode = UnitMode.maintenance
    assert sup._make_status().available_commands == table


def test_start_is_refused_in_manual_and_accepted_in_maintenance(sup) -> None:
    _set(sup, "Idle")
    sup.unit_mode = UnitMode.manual
    ack = sup.apply_command(encode(Command(command="start", request_id="s")))
    assert not ack.accepted and sup.state == "Idle"
    assert ack.reason == "command 'start' is not offered in unit mode 'manual'; allowed: ['abort', 'stop']"
    sup.unit_mode = UnitMode.maintenance
    assert sup.apply_command(encode(Command(command="start"))).accepted


@pytest.mark.parametrize(
    "obj, reason",
    [
        ({"command": "reset", "unit_mode": "manual"}, "either a PackML command or a unit mode change, got both"),
        ({"cntrl_cmd": 1, "unit_mode_code": 2}, "got both ['cntrl_cmd', 'unit_mode_code']"),
        ({"unit_mode": "manual", "unit_mode_code": 3}, "'unit_mode_code' (1..3), got both"),
        ({"unit_mode_code": 4}, "unit_mode_code 4 is unknown; expected one of 1 production, 2 maintenance, 3 manual"),
        ({"unit_mode_code": True}, "unit_mode_code must be an integer code 1..3, got bool True"),
        ({"unit_mode": "auto"}, "unit_mode"),
        ({}, "give exactly one of 'command'"),
        ({"unit_mode": "manual", "params": {"x": 1}}, "a unit mode change takes no params, got ['x']"),
    ],
)
def test_bad_mode_requests_are_refused_naming_what_was_sent(sup, obj: dict, reason: str) -> None:
    _set(sup, "Stopped")
    ack = sup.apply_command(json.dumps({"type": "cellctl/Command", "v": 1, "request_id": "r", **obj}).encode())
    assert not ack.accepted and reason in ack.reason and ack.request_id == "r"
    assert sup.unit_mode == UnitMode.production and sup.state == "Stopped"


def test_modes_and_admin_over_zenoh_and_across_a_restart(cfg) -> None:
    catalog = load_catalog(cfg.path(cfg.catalog))
    cell = build_cell(cfg, identification=(fake_identify, catalog))
    try:
        with FakeCell(cfg, dirty_viewpoints={1}), PlcClient(cfg, "t") as plc:
            time.sleep(0.2)
            ack = plc.unit_mode("maintenance", user="hmi:alice")
            assert ack.accepted and ack.unit_mode == "maintenance" and ack.user == "hmi:alice"
            st = plc.wait_for(lambda s: s.unit_mode == "maintenance", 5)
            assert st is not None and st.unit_mode_code == 2
            plc.to_idle()
            plc.drain()
            ack = plc.send(Command(command="start", user="hmi:bob", request_id="s-1"))
            assert ack.accepted and ack.user == "hmi:bob" and ack.unit_mode == "maintenance"
            res = plc.results.get(timeout=30)
            assert res.verdict == "dirty"
            plc.wait_for(lambda s: s.state == "Complete", 10)
            with open(cfg.path(res.log), "rb") as f:  # the Command is recorded as received, user and all
                cmds = [json.loads(m.data) for _, ch, m in make_reader(f).iter_messages() if ch.topic.endswith("/cmd")]
            assert cmds[0]["user"] == "hmi:bob" and cmds[0]["request_id"] == "s-1"
            plc.to_idle()
            assert plc.unit_mode("manual").accepted  # in Idle
            st = plc.status()
            assert st.unit_mode == "manual"
            assert not plc.command("start").accepted  # manual: no automatic cycle
            admin = st.admin
            assert (admin.prod_processed_count, admin.prod_defective_count) == (1, 1)
            assert admin.last_cycle is not None and admin.last_cycle.verdict == "dirty"
            assert admin.last_cycle.coverage is not None
    finally:
        cell.close()
    cell = build_cell(cfg, identification=(fake_identify, catalog))  # a restart: counted from the index
    try:
        with PlcClient(cfg, "t2") as plc:
            admin = plc.status().admin
        assert (admin.prod_processed_count, admin.prod_defective_count) == (1, 1)
        assert admin.last_cycle is not None and admin.last_cycle.outcome == "completed"
    finally:
        cell.close()


def test_cellctl_cmd_requests_a_unit_mode(cfg, capsys) -> None:
    from cellctl.cli import main

    cell = build_cell(cfg, identification=(None, None))
    try:
        ep = json.dumps(cfg.bus.listen)
        sets = ["--set", f"bus.listen={ep}", "--set", f"bus.connect={ep}", "--timeout", "5"]
        assert main(["cmd", "--unit-mode", "manual", "--user", "cli:test", *sets]) == 0
        ack = json.loads(capsys.readouterr().out.splitlines()[0])
        assert ack["accepted"] and ack["unit_mode"] == "manual" and ack["user"] == "cli:test"
        assert cell.supervisor.unit_mode == UnitMode.manual
        assert main(["cmd", "--unit-mode", "production", "--put", *sets]) == 0
        assert json.loads(capsys.readouterr().out.splitlines()[0])["unit_mode"] == "production"
        assert main(["cmd", "reset", "--unit-mode", "manual", *sets]) == 2  # both: refused before sending
        assert "exactly one" in capsys.readouterr().err
    finally:
        cell.close()
