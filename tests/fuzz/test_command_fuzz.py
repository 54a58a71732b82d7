"""Hostile payloads on the command key: every one gets exactly one Ack, a rejected one changes nothing.

The shipped fuzzer (:mod:`cellctl.bench.reliability.fuzz`, seeded) and hypothesis (derandomized) both
drive a real cell over Zenoh on loopback; the slowed sim robot keeps started cycles in Execute
so that Execute, Held and Suspended are fuzzed too.
"""

from __future__ import annotations

import json

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cellctl.app import build_cell
from cellctl.bench.reliability.fuzz import (
    CATEGORIES,
    FUZZ_OVERRIDES,
    CommandFuzzer,
    FuzzCase,
    FuzzTarget,
    run_fuzz,
    slow_sim_robot,
)
from cellctl.config import load_config
from tests.conftest import cfg_overrides

SEED = 20240601


@pytest.fixture
def cell(tmp_path, port):
    cfg = load_config(None, [*cfg_overrides(tmp_path, port), *FUZZ_OVERRIDES])
    with build_cell(cfg, identification=(None, None)) as c, slow_sim_robot(cfg):
        yield c


def test_the_fuzzer_is_seeded_and_covers_every_category() -> None:
    a = [c.payload for c in CommandFuzzer(SEED).cases(300)]
    assert a == [c.payload for c in CommandFuzzer(SEED).cases(300)]
    assert a != [c.payload for c in CommandFuzzer(SEED + 1).cases(300)]
    seen = {c.category for c in CommandFuzzer(SEED).cases(2000)}
    assert seen == set(CATEGORIES)


def test_two_thousand_seeded_cases_keep_the_contract(cell) -> None:
    out = run_fuzz(cell, 2000, SEED)
    assert out["violations"] == 0, out["violation_examples"]
    assert out["acks"] == out["cases"] == 2000
    assert set(out["by_category"]) == set(CATEGORIES)
    # the valid commands mixed in moved the machine through every waiting state
    assert set(out["cases_by_state"]) >= {"Stopped", "Idle", "Execute", "Held", "Suspended", "Complete", "Aborted"}
    assert out["by_transport"]["query"] > 500 and out["by_transport"]["put"] > 500
    assert out["by_category"]["valid"]["accepted"] > 0
    # nothing hostile got through
    hostile = {c: v for c, v in out["by_category"].items() if c not in ("valid", "oversize", "hostile_request_id")}
    assert all(v["accepted"] == 0 for v in hostile.values()), hostile
    assert cell.supervisor.status.state in {"Stopped", "Idle", "Execute", "Held", "Suspended", "Complete", "Aborted"}


def test_the_checks_catch_a_supervisor_that_breaks_the_contract(cell, monkeypatch) -> None:
    """The oracle is not vacuous: a supervisor accepting a wrong command, or dying on one, is reported."""
    sup = cell.supervisor
    real = sup.apply_command

    def sloppy(payload: bytes):
        if payload.startswith(b"\xef\xbb\xbf"):  # a BOM'd Reset is taken as a Reset
            payload = payload[3:]
        if payload == b"boom":
            raise RuntimeError("boom")
        return real(payload)

    monkeypatch.setattr(sup, "apply_command", sloppy)
    target = FuzzTarget(cell, timeout=1.0)
    try:
        target.send(FuzzCase("bom_and_encodings", b'\xef\xbb\xbf{"type":"cellctl/Command","v":1,"command":"reset"}'))
        target.send(FuzzCase("random_bytes", b"boom"), "put")
    finally:
        target.finish()
    text = "\n".join(target.stats.violations)
    assert "must be refused" in text
    assert "no Ack on cmd/ack" in text and "dispatcher failed" in text


_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12,
)
_field = {
    "type": st.sampled_from(["cellctl/Command", "cellctl/Ack", "Command"]) | _json,
    "v": st.sampled_from([1, 2, 0]) | _json,
    "command": st.sampled_from(["reset", "start", "stop", "hold", "abort", "clear", "jump"]) | _json,
    "cntrl_cmd": st.integers(-2, 12) | _json,
    "request_id": st.text(max_size=140) | _json,
    "params": st.dictionaries(st.sampled_from(["mode", "seed", "perturb_m", "label", "x"]), _json) | _json,
}
_command_like = st.fixed_dictionaries({}, optional=_field).flatmap(
    lambda d: st.dictionaries(st.text(max_size=6), _json, max_size=2).map(lambda extra: {**extra, **d})
)
_HYP = settings(
    derandomize=True,
    max_examples=250,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


def test_arbitrary_bytes_and_json_objects_keep_the_contract(cell) -> None:
    target = FuzzTarget(cell, seed=SEED)

    @_HYP
    @given(data=st.binary(max_size=4096), via=st.sampled_from(["query", "put"]))
    def any_bytes(data: bytes, via: str) -> None:
        target.send(FuzzCase("hypothesis_bytes", data, expect=None), via)

    @_HYP
    @given(obj=_command_like, via=st.sampled_from(["query", "put"]))
    def any_object(obj: dict, via: str) -> None:
        target.send(FuzzCase("hypothesis_json", json.dumps(obj).encode(), expect=None), via)

    try:
        any_bytes()
        any_object()
    finally:
        target.finish()
    assert target.stats.n_violations == 0, target.stats.violations
    assert target.stats.acks == sum(target.stats.sent.values()) >= 400


_mode_fields = {
    **_field,
    "unit_mode": st.sampled_from(["production", "maintenance", "manual", "auto"]) | _json,
    "unit_mode_code": st.integers(-1, 5) | _json,
    "user": st.text(max_size=70) | _json,
}
_mode_like = st.fixed_dictionaries({}, optional=_mode_fields)
_STATES = ["Stopped", "Idle", "Aborted", "Execute", "Held", "Suspended", "Complete", "Clearing", "Resetting"]


def test_unit_mode_fields_keep_the_rules(cfg) -> None:
    """Any mix of command and mode fields: a mode changes only in Stopped/Idle/Aborted and never the state;
    a rejected payload changes nothing; a readable request_id always comes back."""
    from cellctl.messages import UnitMode
    from cellctl.recording.index import CycleIndex
    from cellctl.supervisor.supervisor import Supervisor

    idx = CycleIndex(cfg.path(cfg.recording.index))
    sup = Supervisor(cfg, None, idx)  # no bus: the rules alone, many cases fast

    @_HYP
    @given(obj=_mode_like, state=st.sampled_from(_STATES), mode=st.sampled_from(list(UnitMode)))
    def one(obj: dict, state: str, mode: UnitMode) -> None:
        target = f"Execute.{sup.cycle.initial}" if state == "Execute" else state
        sup.machine.set_state(target)
        sup.unit_mode = mode
        ack = sup.apply_command(json.dumps(obj).encode())
        rid = obj.get("request_id")
        if isinstance(rid, str) and len(rid) <= 128:
            assert ack.request_id == rid
        if not ack.accepted:
            assert sup.state == target and sup.unit_mode == mode and ack.state == state
        elif ack.command is None:  # a mode change
            assert state in ("Stopped", "Idle", "Aborted") and sup.state == target
            assert ack.unit_mode == sup.unit_mode.name
            assert ("unit_mode" in obj) != ("unit_mode_code" in obj) and "command" not in obj and "cntrl_cmd" not in obj
        else:
            assert sup.unit_mode == mode and ack.command in sup.packml.allowed_commands(state)
            assert not (mode == UnitMode.manual and ack.command == "start")

    try:
        one()
    finally:
        idx.close()
