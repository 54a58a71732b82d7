"""The base in the cycle (issue 16 item 3): a manual base is parked by a person/PLC who confirms it
on the command topic; the approaching step waits for it, with a timeout."""

from __future__ import annotations

import time

import pytest

from cellctl.messages import Command
from tests.fakes.workers import FakeCell
from tests.supervisor.test_cycle_over_zenoh import cell, plc  # noqa: F401 - the daemon and PLC fixtures


@pytest.fixture
def cfg(cfg):  # the conftest's cfg with a manual base
    cfg.base.backend = "manual"
    cfg.base.confirm_timeout_s = 20.0
    return cfg


def _confirm(client, station: int):
    return client.send(Command(base_parked=station, request_id=f"base-{station}", user="plc"), 5)


def _waiting(plc, cell, timeout: float = 10.0) -> None:  # noqa: F811
    deadline = time.monotonic() + timeout
    while cell.supervisor.cycles.base.waiting is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert cell.supervisor.cycles.base.waiting == 0
    assert cell.supervisor.state == "Execute.approaching"


def test_the_cycle_waits_for_the_confirmation_then_runs(cfg, cell, plc) -> None:  # noqa: F811
    with FakeCell(cfg) as fake:
        early = _confirm(plc, 0)
        assert not early.accepted and "not waiting for the base" in early.reason
        plc.cmd("reset")
        plc.wait_state("Idle")
        plc.cmd("start")
        _waiting(plc, cell)
        assert "approach" not in fake.calls  # the arm waits for the base
        wrong = _confirm(plc, 3)
        assert not wrong.accepted and "the cell waits for station 0" in wrong.reason
        ok = _confirm(plc, 0)
        assert ok.accepted and ok.command == "base_parked" and ok.user == "plc"
        plc.wait_state("Complete", 20)
        res = plc.results.get(timeout=5)
    assert res.outcome == "completed", res.reason
    assert fake.calls.count("approach") == 1


def test_no_confirmation_aborts_with_the_reason(cfg, cell, plc) -> None:  # noqa: F811
    cfg.base.confirm_timeout_s = 0.5
    cell.supervisor.cycles.base.timeout_s = 0.5
    with FakeCell(cfg) as fake:
        plc.cmd("reset")
        plc.wait_state("Idle")
        plc.cmd("start")
        plc.wait_state("Aborted", 20)
        res = plc.results.get(timeout=5)
    assert res.outcome in ("aborted", "failed")
    assert "not confirmed parked at station 0 within 0.5 s (base.confirm_timeout_s)" in res.reason
    assert "approach" not in fake.calls


def test_a_hold_while_waiting_stops_the_wait_and_unhold_waits_again(cfg, cell, plc) -> None:  # noqa: F811
    with FakeCell(cfg):
        plc.cmd("reset")
        plc.wait_state("Idle")
        plc.cmd("start")
        _waiting(plc, cell)
        assert plc.cmd("hold").accepted
        plc.wait_state("Held")
        time.sleep(0.2)
        assert cell.supervisor.cycles.base.waiting is None  # the wait was stopped with the step
        assert plc.cmd("unhold").accepted
        _waiting(plc, cell)
        assert _confirm(plc, 0).accepted
        plc.wait_state("Complete", 20)
        res = plc.results.get(timeout=5)
    assert res.outcome == "completed", res.reason
