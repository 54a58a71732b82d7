"""``cellctl demo``: the simulated cell end to end, playing the paper's story.

The stories are data (``cellctl/bench/demo/stories/*.yaml``, checked by ``cellctl/bench/demo/stories.py``)
played by ``cellctl/bench/demo/runner.py``; this module only reads the arguments. By default the
whole-bin story (``whole_bin.yaml``): the first cycle plans the whole bin (stations, both surfaces)
and commissions it, the others visit every station; its dirty bin is a wash-and-verify cycle that
must end clean with each round's three pictures (dirt map before, wash path, dirt map after) written
(the whole demo ~10 min on 2 cores, 2026-12-02). ``--no-wash`` plays the plain dirty scan instead.
``--single-station`` plays the story of one station and one surface (``single_station.yaml``: its
clean scans end ``incomplete``, the other surface unseen; its wash cycle's verdict is not checked).
``--stories NAME|FILE`` plays another story file (``wash_only``, or one's own). ``--story N`` plays
story N alone (numbered as the table numbers them), after story 1: the new bin's plan every other
story needs. Exits non-zero if any cycle misbehaves.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from cellctl.cli import add_config_arguments


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the simulated cell end to end (the paper's story)")
    p.add_argument("--out", default=None, help="output folder (default logs/demo-<time>)")
    p.add_argument("--worker-timeout", type=float, default=240.0, help="seconds to wait for the workers to come up")
    # a whole-bin cycle scans ~90 views from 4 stations: 5-7 min on a loaded 2-core machine, longer on the UR emulator
    p.add_argument("--cycle-timeout", type=float, default=1800.0, help="seconds to wait for one cycle's result")
    p.add_argument("--robot", choices=("sim", "ur"), default=None, help="ur: UR backend against `sim ur-controller`")
    p.add_argument(
        "--single-station",
        action="store_true",
        help="one station, one surface per cycle (the story before whole-bin; --stories single_station)",
    )
    p.add_argument(
        "--stories",
        default=None,
        metavar="NAME|FILE",
        help="the story file to play: a shipped one (whole_bin, single_station, wash_only) or a path to a .yaml "
        "(default whole_bin)",
    )
    p.add_argument(
        "--wash",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="the dirty bin is a wash-and-verify cycle (mode=wash_and_verify: wash, re-inspect, clean); "
        "--no-wash: the plain dirty scan",
    )
    p.add_argument(
        "--story",
        type=int,
        action="append",
        metavar="N",
        help="play only story N (repeatable; numbered as the table is), after story 1 (the new bin's plan the others "
        "need); default: every story",
    )
    add_config_arguments(p)
    p.set_defaults(func=run)


def story_file_name(args: argparse.Namespace) -> str:
    """The story file the arguments ask for.

    Raises:
        ConfigError: ``--single-station`` together with ``--stories``.
    """
    from cellctl.errors import ConfigError

    if args.single_station and args.stories is not None:
        raise ConfigError(f"--single-station and --stories {args.stories}: give one (single_station is a story file)")
    return "single_station" if args.single_station else args.stories or "whole_bin"


def run(args: argparse.Namespace) -> int:
    from cellctl.bench.demo.runner import DemoOptions, play
    from cellctl.bench.demo.stories import load_story_file, story_path

    stories = load_story_file(story_path(story_file_name(args)))
    opts = DemoOptions(
        stories=stories,
        wash=args.wash,
        wanted=args.story,
        out=Path(args.out) if args.out else None,
        robot=args.robot,
        worker_timeout=args.worker_timeout,
        cycle_timeout=args.cycle_timeout,
        config=args.config,
        overrides=list(args.overrides),
    )
    return play(opts)
