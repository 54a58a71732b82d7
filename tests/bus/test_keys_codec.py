"""Key expressions are valid Zenoh keys; the codec round-trips and names what is wrong."""

from __future__ import annotations

import json

import pytest
import zenoh

from cellctl.bus import keys
from cellctl.bus.codec import decode, decode_as, encode, json_schemas
from cellctl.errors import ConfigError, ProtocolError
from cellctl.messages import MESSAGE_TYPES, Ack, Command, MoveRequest, PoseMsg, Status


def test_every_key_is_a_canonical_zenoh_key() -> None:
    c = "cell1"
    built = [
        keys.cmd(c),
        keys.cmd_ack(c),
        keys.status(c),
        keys.result(c),
        keys.events(c),
        keys.robot_op(c, "move"),
        keys.robot_joints(c),
        keys.camera_capture(c),
        keys.classifier_classify(c),
        keys.planner_jobs(c),
        keys.planner_job_progress(c, "j1"),
        keys.planner_job_progress(c),
        keys.alive(c, "robot"),
        keys.alive(c, "planner", "p-1"),
        keys.alive_all(c),
        keys.worker_fault(c, "robot"),
    ]
    for k in built:
        assert str(zenoh.KeyExpr(k)) == k
        assert k.startswith("cell/cell1/")


@pytest.mark.parametrize("bad", ["", "cell/1", "a*b", "x" * 65, "-lead"])
def test_bad_cell_ids_are_refused(bad: str) -> None:
    with pytest.raises(ConfigError, match="cell id"):
        keys.cmd(bad)


def test_unknown_role_is_refused() -> None:
    with pytest.raises(ConfigError, match="worker role 'gripper' is unknown"):
        keys.worker_op("cell1", "gripper", "open")


def test_role_from_alive_key() -> None:
    assert keys.role_from_alive_key("cell1", "cell/cell1/alive/planner/p-1") == "planner"
    assert keys.role_from_alive_key("cell1", "cell/cell2/alive/robot") is None


def test_round_trip_every_example() -> None:
    msgs = [
        Command(command="start", request_id="r1", params={"mode": "evaluate"}),
        Command(cntrl_cmd=8),
        Ack(request_id=None, accepted=False, reason="x", state="Stopped"),
        Status(cell="cell1", state="Idle", state_code=4, available_commands=["start"]),
        MoveRequest(camera_pose=PoseMsg(position=(1, 2, 3))),
    ]
    for m in msgs:
        assert decode(encode(m)) == m


def test_command_name_from_either_field() -> None:
    assert Command(cntrl_cmd=10).name == "complete"
    with pytest.raises(ValueError, match="exactly one"):
        Command(command="start", cntrl_cmd=2)


@pytest.mark.parametrize(
    "data, message",
    [
        (b"\xff\xfe", "not valid JSON"),
        (b'"hi"', "must be a JSON object, got str"),
        (b'{"type": "cellctl/Nope", "v": 1}', "message type 'cellctl/Nope' is unknown"),
        (b'{"type": "cellctl/Command", "v": 7, "command": "start"}', "version 7 is not supported"),
        (b'{"type": "cellctl/Command", "v": 1, "command": "start", "colour": "red"}', "colour: Extra inputs"),
        (b'{"type": "cellctl/Command", "v": 1, "cntrl_cmd": "two"}', "cntrl_cmd"),
    ],
)
def test_decode_errors_name_the_problem(data: bytes, message: str) -> None:
    with pytest.raises(ProtocolError) as exc:
        decode(data)
    assert message in str(exc.value)


def test_decode_as_checks_the_type_first() -> None:
    with pytest.raises(ProtocolError, match="expected a cellctl/Ack message, got type 'cellctl/Command'"):
        decode_as(Ack, encode(Command(command="stop")))


def test_schemas_cover_every_message() -> None:
    schemas = json_schemas()
    assert set(schemas) == set(MESSAGE_TYPES)
    assert schemas["cellctl/Command"]["properties"]["type"]["const"] == "cellctl/Command"
    json.dumps(schemas)


def test_schemas_show_the_start_params_and_the_new_status_fields() -> None:
    schemas = json_schemas()
    start = schemas["cellctl/StartParams"]["properties"]
    assert {"mode", "label", "surface", "perturb_m", "seed", "dataset"} <= set(start)
    assert start["mode"]["enum"] == ["evaluate", "collect", "wash_and_verify", "commission"]
    assert {"unit_mode", "unit_mode_code", "admin"} <= set(schemas["cellctl/Status"]["properties"])
    assert {"unit_mode", "unit_mode_code", "user"} <= set(schemas["cellctl/Command"]["properties"])
    assert {"user", "unit_mode"} <= set(schemas["cellctl/Ack"]["properties"])


def test_old_payloads_still_decode_with_the_additive_fields_defaulted() -> None:
    st = decode_as(
        Status, b'{"type":"cellctl/Status","v":1,"cell":"c","state":"Idle","state_code":4,"available_commands":[]}'
    )
    assert (st.unit_mode, st.unit_mode_code, st.admin.prod_processed_count) == ("production", 1, 0)
    ack = decode_as(Ack, b'{"type":"cellctl/Ack","v":1,"request_id":null,"accepted":false,"state":"Idle"}')
    assert ack.user is None and ack.unit_mode is None


@pytest.mark.parametrize(
    "data, rid",
    [
        (b'{"type": "cellctl/Nope", "request_id": "a"}', "a"),
        (b'{"v": 9, "request_id": "b"}', "b"),
        (b'{"request_id": 3}', None),
        (b'{"request_id": "\\ud83d"}', None),  # a lone surrogate: no Ack could carry it
        (b'[{"request_id": "c"}]', None),
        (b'{"request_id": "d", "request_id": "e"}', None),  # repeated key: refused like any payload
        (b"\xff", None),
    ],
)
def test_peek_request_id_reads_it_when_it_can_be_read(data: bytes, rid: str | None) -> None:
    from cellctl.bus.codec import peek_request_id

    assert peek_request_id(data) == rid
    assert peek_request_id(data, max_bytes=2) is None
