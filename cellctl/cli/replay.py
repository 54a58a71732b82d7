"""The cycle-log verbs: ``cellctl replay`` (republish or verify a cycle log), ``cellctl report``
(summary, dirt map PNG) and ``cellctl recover`` (rewrite a cut-short MCAP into a valid one).

An interrupted cycle's log was cut short by the crash; replay and report read the valid copy
recovered when the supervisor restarted, after checking both files against the cycle index.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
from pathlib import Path

from cellctl.cli import add_config_arguments, config_from_args
from cellctl.errors import RecordingError

LIVE_CHECK_S = 2.0
"""How long ``--live`` waits for a supervisor's liveliness token to answer (s); a router answers from its table."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="republish a cycle's MCAP on Zenoh, or --verify it against a fresh supervisor")
    p.add_argument("file")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed factor")
    p.add_argument("--loop", action="store_true")
    p.add_argument("--start-offset", type=float, default=0.0, metavar="S", help="skip the first S seconds")
    p.add_argument("--topics", nargs="+", default=None, metavar="K", help="only these topics")
    p.add_argument(
        "--prefix",
        default=None,
        metavar="P",
        help="prepend P to every key (default: replay/<cycle id>/, outside every cell's keys)",
    )
    p.add_argument(
        "--live",
        action="store_true",
        help="publish on the recorded keys themselves (never commands or acks); refused while the cell's"
        " supervisor is alive",
    )
    p.add_argument(
        "--principal",
        default="replay",
        help="who the replay is on a secured bus (default: replay, which may publish under replay/** only)",
    )
    p.add_argument(
        "--verify", action="store_true", help="re-run the supervisor on the recorded replies; exit 1 on a difference"
    )
    add_config_arguments(p)
    p.set_defaults(func=run_replay)

    r = sub.add_parser("report", help="summarise a cycle and draw its dirt map (--png)")
    r.add_argument("cycle_id")
    r.add_argument("--png", default=None, help="write the dirt map picture here (a folder: FOLDER/<cycle id>.png)")
    add_config_arguments(r)
    r.set_defaults(func=run_report)

    v = sub.add_parser(
        "recover", help="rewrite a cut-short MCAP (no footer: a killed writer) into a valid, indexed one"
    )
    v.add_argument("file", help="the MCAP to recover; it is only read")
    v.add_argument(
        "--out", default=None, metavar="F", help="where to write (default: <stem>.recovered.mcap beside FILE)"
    )
    v.set_defaults(func=run_recover)


def _log_to_read(file: str, index_path: Path) -> str:
    """``file``, or the recovered copy if ``file`` is an interrupted cycle's log (hashes checked)."""
    from cellctl.recording.audit import checked_log, find_cycle

    row = find_cycle(index_path, log=file)
    if row is None:
        return file  # a log from elsewhere: read as it is
    path = checked_log(row)
    if path.resolve() != Path(file).resolve():
        print(
            f"cellctl replay: {file} is the cut-short log of interrupted cycle {row.cycle_id}; reading its"
            f" recovered copy {path} (both sha256 match the index)",
            file=sys.stderr,
        )
    return str(path)


def run_replay(args: argparse.Namespace) -> int:
    from cellctl.recording.replay import read_cycle, republish, verify

    cfg = config_from_args(args)
    file = _log_to_read(args.file, cfg.path(cfg.recording.index))
    if args.verify:
        from cellctl.bus.session import private_bus_overrides
        from cellctl.config import output_overrides

        tmp = tempfile.mkdtemp(prefix="cellctl-verify-")
        args.overrides = [*args.overrides, *private_bus_overrides(), *output_overrides(tmp)]
        cfg = config_from_args(args)
        report = verify(file, cfg)
        print(json.dumps(report.as_dict(), indent=1))
        return 0 if report.ok else 1
    from cellctl.bus.session import open_session

    rec = read_cycle(file)
    if rec.truncated:
        print(
            f"cellctl replay: warning: {file} is damaged; replaying the intact part ({rec.skipped});"
            " cellctl recover writes a valid copy",
            file=sys.stderr,
        )
    if cfg.bus.security_dir is not None:
        # its own principal (cellctl.bus.security), not the config's: the ACL is the last guard against a replay
        cfg.bus.principal = args.principal
    stop = threading.Event()
    from cellctl.cli.worker import install_stop_signals

    install_stop_signals(stop)
    if args.live and args.prefix:
        raise RecordingError(f"--prefix {args.prefix!r} and --live exclude each other")
    with open_session(cfg, "client") as s:
        if args.live:
            _refuse_live_cells(s, sorted({*rec.cells(), cfg.cell_id}))
        n = republish(
            rec,
            s,
            rate=args.rate,
            loop=args.loop,
            start_offset_s=args.start_offset,
            topics=args.topics,
            prefix=args.prefix,
            live=args.live,
            stop=stop,
        )
    from cellctl.bus import keys

    under = "" if args.live else keys.replay_prefix(rec.name) if args.prefix is None else args.prefix
    print(
        json.dumps(
            {
                "published": n,
                "under": under or "(the recorded keys, commands left out)",
                "messages": len(rec.messages),
                "truncated": rec.truncated,
                "skipped": rec.skipped,
            }
        )
    )
    return 0


def _refuse_live_cells(session, cells: list[str]) -> None:  # zenoh.Session, imported lazily
    """Raise if the supervisor of any of ``cells`` holds its liveliness token: its keys are live."""
    from cellctl.bus import keys

    for cell in cells:
        key = keys.alive(cell, "supervisor")
        if any(r.ok is not None for r in session.liveliness().get(key, timeout=LIVE_CHECK_S)):
            raise RecordingError(
                f"cell {cell!r} has a live supervisor ({key!r} answered): --live replay onto its keys is refused;"
                " replay under the default replay/<cycle>/ prefix, or stop that cell's daemon first"
            )


def run_report(args: argparse.Namespace) -> int:
    import numpy as np

    from cellctl.geometry.catalog import load_catalog
    from cellctl.recording.audit import checked_log, find_cycle
    from cellctl.recording.dirt_map import draw_dirt_map
    from cellctl.recording.replay import read_cycle

    cfg = config_from_args(args)
    row = find_cycle(cfg.path(cfg.recording.index), cycle_id=args.cycle_id)
    if row is None:
        raise RecordingError(f"cycle {args.cycle_id!r} is not in the index {cfg.path(cfg.recording.index)}")
    log_file = checked_log(row)
    rec = read_cycle(log_file)
    results = [m.json() for m in rec.messages if m.schema == "cellctl/CycleResult"]
    if not results and row.outcome == "interrupted":
        return _report_interrupted(row, rec, args.png)
    if not results:
        raise RecordingError(f"cycle {args.cycle_id!r} has no result in {log_file} (outcome {row.outcome})")
    res = results[-1]
    summary = {k: res.get(k) for k in ("cycle_id", "outcome", "reason", "verdict", "coverage", "plan_id")}
    summary["bin"] = res.get("bin", {}).get("type")
    summary["viewpoints"] = [
        (v["index"], v.get("label"), v.get("p_dirty"), v.get("uncertain")) for v in res["viewpoints"]
    ]
    print(json.dumps(summary, indent=1))
    if args.png:
        png = _png_target(args.png, args.cycle_id)
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
        try:
            draw_dirt_map(
                mesh,
                dm,
                png,
                f"cycle {args.cycle_id} verdict {res.get('verdict')}",
                np.array(cams) if cams else None,
            )
        except OSError as err:
            raise RecordingError(f"cannot write the dirt map to {str(png)!r}: {err.strerror or err}") from err
        print(f"wrote {png}", file=sys.stderr)
    return 0


def _png_target(given: str, cycle_id: str) -> Path:
    """Where ``--png`` writes: a folder gets ``<cycle id>.png`` inside it; a name without ``.png`` gets the
    suffix (the plotting library would add it behind our back, and we would name the wrong file)."""
    p = Path(given)
    if p.is_dir():
        return p / f"{cycle_id}.png"
    return p if p.suffix.lower() == ".png" else p.with_name(p.name + ".png")


def _report_interrupted(row, rec, png: str | None) -> int:  # CycleRow, RecordedCycle
    """An interrupted cycle has no CycleResult: say what its recovered log holds, up to the cut."""

    statuses = [m.json() for m in rec.messages if m.schema == "cellctl/Status"]
    last = statuses[-1] if statuses else {}
    summary = {
        "cycle_id": row.cycle_id,
        "outcome": row.outcome,
        "reason": row.reason,
        "log": row.log_path,
        "log_sha256": row.log_sha256,
        "recovered_log": row.recovered_path,
        "recovered_sha256": row.recovered_sha256,
        "messages": len(rec.messages),
        "images": sum(1 for m in rec.messages if m.schema == "foxglove.CompressedImage"),
        "last_state": last.get("state", "") + (f".{last['step']}" if last.get("step") else ""),
    }
    print(json.dumps(summary, indent=1))
    if png:
        raise RecordingError(f"cycle {row.cycle_id!r} was interrupted: it has no dirt map to draw")
    return 0


def run_recover(args: argparse.Namespace) -> int:
    from cellctl.recording.recover import recover_mcap

    found = recover_mcap(args.file, args.out)
    print(json.dumps(found.as_dict(), indent=1))
    return 0
