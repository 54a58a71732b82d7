"""Operator / PLC-emulator tools: ``cellctl cmd``, ``cellctl status``, ``cellctl cycles``."""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING

from cellctl.cli import add_config_arguments, config_from_args
from cellctl.errors import CellError

if TYPE_CHECKING:
    from cellctl.messages import Status

COMMANDS = ["reset", "start", "stop", "hold", "unhold", "suspend", "unsuspend", "abort", "clear", "complete"]
UNIT_MODES = ["production", "maintenance", "manual"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("cmd", help="send a PackML command (or a unit mode change) to the cell and print the Ack")
    p.add_argument("command", nargs="?", choices=COMMANDS, help="the PackML command (omit with --unit-mode)")
    p.add_argument(
        "--unit-mode",
        choices=UNIT_MODES,
        default=None,
        help="request this PackML unit mode instead of a command (accepted in Stopped, Idle, Aborted)",
    )
    p.add_argument(
        "--base-parked",
        type=int,
        default=None,
        metavar="STATION",
        help="manual base: confirm the base is parked at this station (the cell waits in approaching)",
    )
    p.add_argument("--user", default=None, help="who sends it, recorded and echoed in the Ack (e.g. hmi:alice)")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE", help="start params, e.g. mode=collect")
    p.add_argument("--wait", metavar="STATE", default=None, help="then wait until the cell reaches this PackML state")
    p.add_argument("--timeout", type=float, default=30.0, help="seconds for the Ack and for --wait")
    p.add_argument("--put", action="store_true", help="send by put (Ack read from cmd/ack) instead of query")
    add_config_arguments(p)
    p.set_defaults(func=run_cmd)

    s = sub.add_parser("status", help="print the cell status (JSON)")
    s.add_argument("--watch", action="store_true", help="print every status update until Ctrl-C")
    s.add_argument("--timeout", type=float, default=5.0)
    add_config_arguments(s)
    s.set_defaults(func=run_status)

    c = sub.add_parser("cycles", help="list cycles from the cycle index")
    c.add_argument("--last", type=int, default=20)
    c.add_argument("--json", action="store_true")
    add_config_arguments(c)
    c.set_defaults(func=run_cycles)


def _parse_params(items: list[str]) -> dict:
    from cellctl.config import safe_yaml_load

    out = {}
    for it in items:
        if "=" not in it:
            raise CellError(f"--param {it!r}: expected KEY=VALUE")
        k, v = it.split("=", 1)
        out[k] = safe_yaml_load(v, f"--param {k}")
    return out


def run_cmd(args: argparse.Namespace) -> int:
    from cellctl.bus.plc_client import PlcClient
    from cellctl.messages import Command, now_iso
    from cellctl.supervisor.definition import PackMLState

    states = [s.name for s in PackMLState if s != PackMLState.Undefined]
    if args.wait is not None and args.wait not in states:
        # refused before anything is sent: a command sent with a wait that can never end is worse than none
        raise CellError(f"--wait {args.wait!r} is not a PackML state; expected one of {states}")
    cfg = config_from_args(args)
    given = [x for x in (args.command, args.unit_mode, args.base_parked) if x is not None]
    if len(given) != 1:
        raise CellError("cellctl cmd: give a PackML command, --unit-mode MODE or --base-parked STATION (exactly one)")
    if args.command is None and args.param:
        raise CellError(f"cellctl cmd: only a PackML command takes --param, got {args.param}")
    params = _parse_params(args.param)
    # the one client of the PLC contract: request ids cli-<boot token>-<n>, Statuses subscribed before the send
    with PlcClient(cfg, "cli") as plc:
        cmd = Command(
            command=args.command,
            unit_mode=args.unit_mode,
            base_parked=args.base_parked,
            user=args.user,
            request_id=plc.next_id(),
            params=params,
            stamp=now_iso(),
        )
        ack = plc.send(cmd, args.timeout, put=args.put)
        print(ack.model_dump_json())
        if not ack.accepted:
            return 1
        if args.wait:
            seen = [ack.state]

            def reached(st: Status) -> bool:
                seen.append(st.state)
                return st.state == args.wait

            if ack.state != args.wait and plc.wait_for(reached, args.timeout) is None:
                print(f"cellctl cmd: timed out waiting for {args.wait!r}; state is {seen[-1]!r}", file=sys.stderr)
                return 3
            print(json.dumps({"reached": args.wait}))
    return 0


def run_status(args: argparse.Namespace) -> int:
    from cellctl.bus.plc_client import PlcClient

    cfg = config_from_args(args)
    with PlcClient(cfg, "cli") as plc:
        print(plc.status(args.timeout).model_dump_json(), flush=True)
        if args.watch:
            plc.drain()  # from now on
            try:
                while True:
                    print(plc.statuses.get().model_dump_json(), flush=True)
            except KeyboardInterrupt:
                return 0
    return 0


def run_cycles(args: argparse.Namespace) -> int:
    from dataclasses import asdict

    from cellctl.recording.index import CycleIndex

    if args.last < 1:
        raise CellError(f"--last {args.last}: expected a number of cycles >= 1")
    cfg = config_from_args(args)
    idx = CycleIndex(cfg.path(cfg.recording.index))
    rows = idx.last(args.last)
    idx.close()
    if args.json:
        print(json.dumps([asdict(r) for r in rows], indent=1))
        return 0
    print(f"{'cycle':28} {'outcome':16} {'verdict':10} {'bin':12} {'plan':14} reason")
    for r in rows:
        print(
            f"{r.cycle_id:28} {r.outcome or 'running':16} {r.verdict or '-':10} {r.bin_type or '-':12} "
            f"{(r.plan_id or '-')[:14]:14} {(r.reason or '')[:70]}"
        )
    return 0
