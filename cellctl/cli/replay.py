"""``cellctl replay`` (republish or verify a cycle log) and ``cellctl report`` (dirt map PNG)."""

from __future__ import annotations

import argparse
import json
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
    p.add_argument(
        "--verify", action="store_true", help="re-run the supervisor on the recorded replies; exit 1 on a difference"
    )
    add_config_arguments(p)
    p.set_defaults(func=run_replay)

    r = sub.add_parser("report", help="summarise a cycle and draw its dirt map (--png)")
    r.add_argument("cycle_id")
    r.add_argument("--png", default=None, help="write the dirt map picture here")
    add_config_arguments(r)
    r.set_defaults(func=run_report)


def run_replay(args: argparse.Namespace) -> int:
    from cellctl.recording.replay import read_cycle, republish, verify

    if args.verify:
        from cellctl.bus.session import private_bus_overrides
        from cellctl.config import output_overrides

        tmp = tempfile.mkdtemp(prefix="cellctl-verify-")
        args.overrides = [*args.overrides, *private_bus_overrides(), *output_overrides(tmp)]
        cfg = config_from_args(args)
        report = verify(args.file, cfg)
        print(json.dumps(report.as_dict(), indent=1))
        return 0 if report.ok else 1
    from cellctl.bus.session import open_session

    cfg = config_from_args(args)
    rec = read_cycle(args.file)
    if rec.truncated:
        print(
            f"cellctl replay: warning: {args.file} is damaged; replaying the intact part ({rec.skipped})",
            file=sys.stderr,
        )
    stop = threading.Event()
    from cellctl.cli.worker import install_stop_signals

    install_stop_signals(stop)
    with open_session(cfg, "client") as s:
        n = republish(
            rec,
            s,
            rate=args.rate,
            loop=args.loop,
            start_offset_s=args.start_offset,
            topics=args.topics,
            prefix=args.prefix,
            stop=stop,
        )
    print(
        json.dumps({"published": n, "messages": len(rec.messages), "truncated": rec.truncated, "skipped": rec.skipped})
    )
    return 0


def run_report(args: argparse.Namespace) -> int:
    from pathlib import Path

    import numpy as np

    from cellctl.errors import RecordingError
    from cellctl.geometry.catalog import load_catalog
    from cellctl.recording.dirt_map import draw_dirt_map
    from cellctl.recording.index import CycleIndex
    from cellctl.recording.replay import read_cycle

    cfg = config_from_args(args)
    idx = CycleIndex(cfg.path(cfg.recording.index))
    row = idx.get(args.cycle_id)
    idx.close()
    if row is None:
        raise RecordingError(f"cycle {args.cycle_id!r} is not in the index {cfg.path(cfg.recording.index)}")
    rec = read_cycle(row.log_path)
    results = [m.json() for m in rec.messages if m.schema == "cellctl/CycleResult"]
    if not results:
        raise RecordingError(f"cycle {args.cycle_id!r} has no result in {row.log_path} (outcome {row.outcome})")
    res = results[-1]
    summary = {k: res.get(k) for k in ("cycle_id", "outcome", "reason", "verdict", "coverage", "plan_id")}
    summary["bin"] = res.get("bin", {}).get("type")
    summary["viewpoints"] = [
        (v["index"], v.get("label"), v.get("p_dirty"), v.get("uncertain")) for v in res["viewpoints"]
    ]
    print(json.dumps(summary, indent=1))
    if args.png:
        dm = res.get("dirt_map")
        if not dm:
            raise RecordingError(f"cycle {args.cycle_id!r} has no dirt map (outcome {res['outcome']})")
        mesh = load_catalog(cfg.path(cfg.catalog)).load_mesh(summary["bin"])
        from cellctl.messages import PoseMsg

        T_base_bin = PoseMsg.model_validate(res["bin"]["pose"]).matrix()
        cams = []
        for v in res["viewpoints"]:
            if v.get("camera_pose"):
                p = PoseMsg.model_validate(v["camera_pose"]).matrix()
                cams.append((np.linalg.inv(T_base_bin) @ p)[:3, 3])
        draw_dirt_map(
            mesh,
            dm,
            Path(args.png),
            f"cycle {args.cycle_id} verdict {res.get('verdict')}",
            np.array(cams) if cams else None,
        )
        print(f"wrote {args.png}", file=sys.stderr)
    return 0
