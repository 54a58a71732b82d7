"""Checking one command payload: decode, the unit mode, the state's allowed commands, Start params.

Pure functions of the payload and the cell's state: no bus, no machine; the dispatcher applies
what they accept and sends the Ack they build.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

from cellctl.bus.codec import decode_as, peek_request_id
from cellctl.errors import ProtocolError, TransitionRejected
from cellctl.messages import Ack, Command, StartParams, UnitMode
from cellctl.supervisor.unit_modes import commands_in_mode, mode_change_refusal, start_mode_refusal

__all__ = ["Accepted", "check_command", "recorded_command"]


@dataclass(frozen=True)
class Accepted:
    """A command that passed every check, ready to apply."""

    cmd: Command
    start: StartParams | None = None
    """The checked Start params (``start`` only)."""
    mode: UnitMode | None = None
    """The unit mode asked for (a mode change only)."""
    base_station: int | None = None
    """The station a manual base is confirmed parked at (a base confirmation only)."""

    def refuse(self, state: str, reason: str, mode: UnitMode) -> Ack:
        """The refusing Ack of a command that passed the checks but cannot be applied now."""
        cmd = self.cmd
        return Ack(
            request_id=cmd.request_id,
            command=None if self.mode is not None else cmd.name,
            accepted=False,
            reason=reason,
            state=state,
            user=cmd.user,
            unit_mode=mode.wire_name,
        )

    def ack(self, state: str, mode: UnitMode | None = None) -> Ack:
        """The accepting Ack: ``state`` after applying, ``mode`` the unit mode now (default: the one asked for)."""
        cmd, now = self.cmd, mode or self.mode
        return Ack(
            request_id=cmd.request_id,
            command=None if self.mode is not None else cmd.name,
            accepted=True,
            state=state,
            user=cmd.user,
            unit_mode=now.wire_name if now is not None else None,
        )


def check_command(payload: bytes, *, max_bytes: int, state: str, allowed: list[str], mode: UnitMode) -> Accepted | Ack:
    """Accept the command in ``payload`` or build the rejecting Ack.

    Args:
        state: the PackML state (top level) the command arrives in.
        allowed: the PackML commands that state accepts (the table, before the unit mode).
        mode: the unit mode now.
    """
    try:
        cmd = decode_as(Command, payload, max_bytes)
    except ProtocolError as err:
        # a PLC matches Acks to requests: name the request whenever the payload lets us read it
        rid = peek_request_id(payload, max_bytes)
        return Ack(request_id=rid, accepted=False, reason=str(err), state=state, unit_mode=mode.wire_name)

    def reject(reason: str, command: str | None) -> Ack:
        return Ack(
            request_id=cmd.request_id,
            command=command,
            accepted=False,
            reason=reason,
            state=state,
            user=cmd.user,
            unit_mode=mode.wire_name,
        )

    if cmd.base_parked is not None:
        # any state: the supervisor checks that a park is awaited (only a running approach waits)
        if cmd.params:
            return reject(f"a base confirmation takes no params, got {sorted(cmd.params)}", "base_parked")
        return Accepted(cmd, base_station=cmd.base_parked)
    requested = cmd.requested_mode
    if requested is not None:
        if cmd.params:
            return reject(f"a unit mode change takes no params, got {sorted(cmd.params)}", None)
        refusal = mode_change_refusal(requested, state)
        return reject(refusal, None) if refusal else Accepted(cmd, mode=requested)
    name = cmd.name
    in_mode = commands_in_mode(allowed, mode)
    if name not in in_mode:
        if name in allowed:
            reason = f"command {name!r} is not offered in unit mode {mode.name!r}; allowed: {sorted(in_mode) or 'none'}"
        else:
            reason = str(TransitionRejected(name, state, in_mode))
        return reject(reason, name)
    if name == "start":
        try:
            start = StartParams.from_params(cmd.params)
        except ProtocolError as err:
            return reject(str(err), name)
        if refusal := start_mode_refusal(start.mode, mode):
            return reject(refusal, name)
        if start.mode == "commission" and not cmd.user:
            # the operator declares the bin clean: a declaration nobody signed cannot be audited
            return reject("start mode 'commission' needs 'user' (who declares the bin clean), got none", name)
        return Accepted(cmd, start=start)
    if cmd.params:
        return reject(f"command {name!r} takes no params, got {sorted(cmd.params)}", name)
    return Accepted(cmd)


def recorded_command(payload: bytes) -> tuple[str, bytes | dict[str, object]]:
    """What the cycle log keeps of a received payload: (schema, data).

    The command as sent when it is a JSON object (even a rejected one: audit), else the
    rejected bytes as text, cut at 1 KiB.
    """
    try:
        is_command = isinstance(json.loads(payload), dict)
    except (ValueError, RecursionError):  # a rejected payload may be any bytes, nested arrays too
        is_command = False
    if is_command:
        return "cellctl/Command", payload
    return "cellctl.RejectedPayload", {"raw": payload[:1024].decode("utf-8", "replace"), "bytes": len(payload)}
