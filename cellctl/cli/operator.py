"""Operator / PLC-emulator tools: ``cellctl cmd``, ``cellctl status``, ``cellctl cycles``."""

from __future__ import annotations

import argparse
import json
import queue
import sys
import time

from cellctl.cli import add_config_arguments, config_from_args
from cellctl.errors import CellError, WorkerTimeout, WorkerUnavailable

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
    import zenoh

    from cellctl.bus import keys
    from cellctl.bus.codec import decode_as, encode
    from cellctl.bus.security import acl_hint
    from cellctl.bus.session import open_session
    from cellctl.messages import Ack, Command, Status, now_iso
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
    cmd = Command(
        command=args.command,
        unit_mode=args.unit_mode,
        base_parked=args.base_parked,
        user=args.user,
        request_id=f"cli-{time.time_ns()}",
        params=_parse_params(args.param),
        stamp=now_iso(),
    )
    with open_session(cfg, "client") as s:
        statuses: queue.Queue[Status] = queue.Queue()
        sub = s.declare_subscriber(
            keys.status(cfg.cell_id), lambda smp: statuses.put(decode_as(Status, smp.payload.to_bytes()))
        )
        acks: queue.Queue[Ack] = queue.Queue()
        if args.put:
            asub = s.declare_subscriber(
                keys.cmd_ack(cfg.cell_id), lambda smp: acks.put(decode_as(Ack, smp.payload.to_bytes()))
            )
            time.sleep(0.1)  # let the subscription reach the router before the put
            # BLOCK: the default (DROP) may drop a put at a full transmission queue, and nothing would answer
            s.put(keys.cmd(cfg.cell_id), encode(cmd), congestion_control=zenoh.CongestionControl.BLOCK)
            try:
                while True:
                    ack = acks.get(timeout=args.timeout)
                    if ack.request_id == cmd.request_id:
                        break
            except queue.Empty:
                raise WorkerTimeout(
                    f"no Ack on {keys.cmd_ack(cfg.cell_id)} within {args.timeout:g} s"
                    + acl_hint(cfg.bus, keys.cmd(cfg.cell_id))
                ) from None
            asub.undeclare()
        else:
            replies = list(s.get(keys.cmd(cfg.cell_id), payload=encode(cmd), timeout=args.timeout))
            if not replies:
                raise WorkerUnavailable(
                    f"no cellctl daemon serves {keys.cmd(cfg.cell_id)!r}; is `cellctl run` running?"
                    + acl_hint(cfg.bus, keys.cmd(cfg.cell_id))
                )
            if replies[0].ok is None:
                raise WorkerTimeout(f"the daemon did not answer within {args.timeout:g} s")
            ack = decode_as(Ack, replies[0].ok.payload.to_bytes())
        print(ack.model_dump_json())
        if not ack.accepted:
            return 1
        if args.wait:
            deadline = time.monotonic() + args.timeout
            state = ack.state
            while state != args.wait:
                left = deadline - time.monotonic()
                if left <= 0:
                    print(f"cellctl cmd: timed out waiting for {args.wait!r}; state is {state!r}", file=sys.stderr)
                    return 3
                try:
                    st = statuses.get(timeout=left)
                except queue.Empty:
                    continue
                state = st.state
            print(json.dumps({"reached": state}))
        sub.undeclare()
    return 0


def query_status(session, cfg, timeout: float):
    from cellctl.bus import keys
    from cellctl.bus.codec import decode_as
    from cellctl.messages import Status

    replies = list(session.get(keys.status(cfg.cell_id), timeout=timeout))
    if not replies:
        raise WorkerUnavailable(f"no cellctl daemon serves {keys.status(cfg.cell_id)!r}; is `cellctl run` running?")
    if replies[0].ok is None:
        raise WorkerTimeout(f"the daemon did not answer a status query within {timeout:g} s")
    return decode_as(Status, replies[0].ok.payload.to_bytes())


def run_status(args: argparse.Namespace) -> int:
    from cellctl.bus import keys
    from cellctl.bus.session import open_session

    cfg = config_from_args(args)
    with open_session(cfg, "client") as s:
        print(query_status(s, cfg, args.timeout).model_dump_json(), flush=True)
        if args.watch:
            q: queue.Queue[bytes] = queue.Queue()
            s.declare_subscriber(keys.status(cfg.cell_id), lambda smp: q.put(smp.payload.to_bytes()))
            try:
                while True:
                    print(q.get().decode(), flush=True)
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
