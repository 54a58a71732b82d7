"""Every (state, command) pair against the PackML table of notes/supervisor.md.

The expected table is written here independently of states/packml.yaml, so a wrong YAML
fails this test.
"""

from __future__ import annotations

import pytest

from cellctl.bus.codec import encode
from cellctl.messages import Command
from cellctl.recording.index import CycleIndex
from cellctl.supervisor.supervisor import Supervisor

STATES = [
    "Clearing",
    "Stopped",
    "Starting",
    "Idle",
    "Suspended",
    "Execute",
    "Stopping",
    "Aborting",
    "Aborted",
    "Holding",
    "Held",
    "Unholding",
    "Suspending",
    "Unsuspending",
    "Resetting",
    "Completing",
    "Complete",
]
STOP_FROM = {
    "Idle",
    "Starting",
    "Execute",
    "Completing",
    "Complete",
    "Resetting",
    "Holding",
    "Held",
    "Unholding",
    "Suspending",
    "Suspended",
    "Unsuspending",
}
ABORT_FROM = set(STATES) - {"Aborting", "Aborted"}  # abort is allowed everywhere else
EXPECTED: dict[tuple[str, str], str] = {
    ("Idle", "start"): "Starting",
    ("Execute", "complete"): "Completing",
    ("Execute", "hold"): "Holding",
    ("Execute", "suspend"): "Suspending",
    ("Complete", "reset"): "Resetting",
    ("Stopped", "reset"): "Resetting",
    ("Held", "unhold"): "Unholding",
    ("Suspended", "unsuspend"): "Unsuspending",
    ("Aborted", "clear"): "Clearing",
    **{(s, "stop"): "Stopping" for s in STOP_FROM},
    **{(s, "abort"): "Aborting" for s in ABORT_FROM},
}
COMMANDS = ["reset", "start", "stop", "hold", "unhold", "suspend", "unsuspend", "abort", "clear", "complete"]


@pytest.fixture
def sup(cfg):
    idx = CycleIndex(cfg.path(cfg.recording.index))
    s = Supervisor(cfg, None, idx)  # never started: no bus, the table alone
    yield s
    idx.close()


@pytest.mark.parametrize("state", STATES)
@pytest.mark.parametrize("command", COMMANDS)
def test_state_command_pair(sup, state: str, command: str) -> None:
    target = f"Execute.{sup.cycle.initial}" if state == "Execute" else state
    sup.machine.set_state(target)
    ack = sup.apply_command(encode(Command(command=command, request_id="x")))
    expected = EXPECTED.get((state, command))
    if expected is None:
        assert not ack.accepted, f"{command} must be rejected in {state}"
        assert f"not allowed in state {state!r}" in ack.reason
        assert sup.state == target, "a rejected command changes nothing"
    else:
        assert ack.accepted, ack.reason
        assert sup.top_state == expected
        assert ack.state == expected


@pytest.mark.parametrize("code, name", [(1, "reset"), (2, "start"), (3, "stop"), (8, "abort"), (9, "clear")])
def test_cntrl_cmd_codes_map_to_packml_commands(sup, code: int, name: str) -> None:
    ack = sup.apply_command(encode(Command(cntrl_cmd=code)))
    assert ack.command == name


def test_available_commands_follow_the_table(sup) -> None:
    for state in STATES:
        expected = sorted(c for c in COMMANDS if (state, c) in EXPECTED)
        assert sorted(sup.packml.allowed_commands(state)) == expected, state
