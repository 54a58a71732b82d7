"""``cellctl replay`` (republish or verify a cycle log) and ``cellctl report`` (dirt map PNG)."""

from __future__ import annotations

import argparse
import json
import socket
import sys
import tempfile
import threading

from cellctl.cli import add_config_arguments, config_from_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="republish a cycle's MCAP on Zenoh, or --verify it against a fresh supervisor")
    p.add_argument("file")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed factor")
    p.add_argument("--loop", action="store_true")
    p.add_argument("--start-offset", type=float, default=0.0, metavar="S", help="skip the first S seconds")
    p.add_argument("--topics", nargs="+", default=None, metavar="K", help="only these topics")
    p.add_argument("--prefix", default="", metavar="P", help="prepend P to every key (e.g. replay/)")
    p.add_argument("--verify", action="store_true", help="re-run the supervisor on the recorded replies; exit 1 on a difference")
    add_config_arguments(p)
    p.set_defaults(func=run_replay)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_replay(args: argparse.Namespace) -> int:
    from cellctl.recording.replay import read_cycle, republish, verify

    if args.verify:
        port = _free_port()
        tmp = tempfile.mkdtemp(prefix="cellctl-verify-")
        ep = f'["tcp/127.0.0.1:{port}"]'
        args.overrides = [*args.overrides, f"bus.listen={ep}", f"bus.connect={ep}", f"recording.dir={tmp}",
                          f"recording.index={tmp}/cells.db"]
        cfg = config_from_args(args)
        report = verify(args.file, cfg)
        print(json.dumps(report.as_dict(), indent=1))
        return 0 if report.ok else 1
    from cellctl.bus.session import open_session

    cfg = config_from_args(args)
    rec = read_cycle(args.file)
    if rec.truncated:
        print(f"cellctl replay: warning: {args.file} is damaged; replaying the intact part ({rec.skipped})", file=sys.stderr)
    stop = threading.Event()
    from cellctl.cli.worker import install_stop_signals

    install_stop_signals(stop)
    with open_session(cfg, "client") as s:
        n = republish(rec, s, rate=args.rate, loop=args.loop, start_offset_s=args.start_offset, topics=args.topics,
                      prefix=args.prefix, stop=stop)
    print(json.dumps({"published": n, "messages": len(rec.messages), "truncated": rec.truncated, "skipped": rec.skipped}))
    return 0
