"""The request-id window remembers only what the supervisor acted on (no bus: the command path alone).

A refused command — not allowed in this state, a stale or future stamp, or a repeat — must not use up
its ``request_id``: otherwise anyone who can put on ``cmd`` could send refused commands carrying the
PLC's next ids and have the PLC's real commands refused as replays. Mode changes are deduplicated
like PackML commands.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Iterator

import pytest

from cellctl.bus.codec import encode
from cellctl.config import CellConfig
from cellctl.messages import Command
from cellctl.recording.index import CycleIndex
from cellctl.supervisor.supervisor import Supervisor


@pytest.fixture
def sup(cfg: CellConfig) -> Iterator[Supervisor]:
    idx = CycleIndex(cfg.path(cfg.recording.index))
    try:
        yield Supervisor(cfg, None, idx)  # never started: apply_command on the caller's thread
    finally:
        idx.close()


def _at(minutes: float) -> str:
    return (dt.datetime.now(dt.UTC) + dt.timedelta(minutes=minutes)).isoformat()


def test_a_refused_command_does_not_use_up_its_request_id(sup: Supervisor) -> None:
    refused = [
        Command(command="hold", request_id="plc-7"),  # not allowed in Stopped
        Command(command="reset", request_id="plc-7", stamp=_at(-60)),  # an hour old
        Command(command="reset", request_id="plc-7", stamp=_at(+5)),  # five minutes ahead
        Command(unit_mode="maintenance", request_id="plc-7", params={"x": 1}),  # a mode change takes no params
    ]
    for cmd in refused:
        assert not sup.apply_command(encode(cmd)).accepted, cmd
    assert sup.top_state == "Stopped"
    # the PLC's real command with that id is still served
    assert sup.apply_command(encode(Command(command="reset", request_id="plc-7", stamp=_at(0)))).accepted
    assert sup.top_state != "Stopped"


def test_a_mode_change_is_acted_on_once_per_request_id(sup: Supervisor) -> None:
    first = sup.apply_command(encode(Command(unit_mode="maintenance", request_id="m-1", stamp=_at(0))))
    assert first.accepted and sup.unit_mode.name == "maintenance"
    assert sup.apply_command(encode(Command(unit_mode="production", request_id="m-2"))).accepted
    again = sup.apply_command(encode(Command(unit_mode="maintenance", request_id="m-1", stamp=_at(0))))
    assert not again.accepted and "request_id 'm-1' was already acted on" in (again.reason or "")
    assert sup.unit_mode.name == "production"
