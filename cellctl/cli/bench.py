"""``cellctl bench <what>``: measurements that print one JSON object on stdout.

Each bench is a library function ``module:function`` taking a typed
:class:`~cellctl.bench.options.BenchOptions` and returning a dict; this module only turns the
flags into those options. Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from pathlib import Path

from cellctl.bench.options import BenchOptions
from cellctl.cli import add_config_arguments

# name -> (module:function, help): the bench lives in cellctl/bench/<name>.py (or a folder of its concept).
# Add yours here.
BENCHES: dict[str, tuple[str, str]] = {
    "bus": ("cellctl.bench.bus:bench_bus", "command→ack and status latency on loopback"),
    "cycle": ("cellctl.bench.cycle:bench_cycle", "supervisor overhead per viewpoint, cycle time, cycles/hour"),
    "classify": (
        "cellctl.bench.classify.variants:bench_classify",
        "classifier latency/throughput/accuracy per variant",
    ),
    "reference": (
        "cellctl.bench.classify.reference:bench_reference",
        "reference views: fit + measure the change-vs-reference decision on twin pairs, mirror tolerance, latency",
    ),
    "pose": ("cellctl.bench.pose:bench_pose", "ChArUco bin-pose accuracy vs ground truth at 0.5-2 m"),
    "sim": ("cellctl.bench.sim:bench_sim", "twin: IK per pose, collision check per configuration, render per frame"),
    "plan": (
        "cellctl.bench.planning.plans:bench_plan",
        "planner: fast vs paper mode, case-study bin, p_SP 10/40 (--n: paper RRT* budget in 0.1 s)",
    ),
    "whole-bin": (
        "cellctl.bench.planning.plans:bench_whole_bin",
        "whole-bin plans: catalog bins + foreign meshes (--family: the shape family), stations, coverage per "
        "surface, cycle time (--n seeds)",
    ),
    "faults": (
        "cellctl.bench.reliability.faults:bench_faults",
        "kill/freeze each worker at each cycle step: detection time, safe state, recovery",
    ),
    "fuzz": ("cellctl.bench.reliability.fuzz:bench_fuzz", "seeded hostile payloads to the command key (--n cases)"),
    "soak": (
        "cellctl.bench.reliability.soak:bench_soak",
        "sim cycles back to back (--n cycles): cycles/hour, RSS, open files",
    ),
    "inspect": (
        "cellctl.bench.classify.inspect:bench_inspect",
        "bin verdict + per-face dirt map vs ground truth over seeded sim cycles (--cycles N)",
    ),
    "hmi": ("cellctl.bench.hmi:bench_hmi", "GET /api/status p50/p99 of a separate HMI process while sim cycles run"),
    "cluster": (
        "cellctl.bench.reliability.cluster:bench_cluster",
        "3 cells, planner pool, PLC host in network namespaces: cycles, jobs, 1 vs 2 workers, link faults (root)",
    ),
    "opcua": (
        "cellctl.bench.opcua:bench_opcua",
        "command -> StateCurrent through the OPC UA gateway beside raw Zenoh (--n rounds)",
    ),
    "ur": (
        "cellctl.bench.ur:bench_ur",
        "UR backend vs the emulated controller: protective stop → safe state, supervisor loss → stopped, tracking",
    ),
    "wash": (
        "cellctl.bench.wash:bench_wash",
        "wash-and-verify rounds on seeded dirty twin bins: dirty area covered, rounds, saving (--cycles N)",
    ),
}

COMMISSIONED = "cellctl.bench.classify.inspect_commissioned:bench_inspect_commissioned"
"""``bench inspect --commissioned`` (or ``--merge``): every view decided with and without its reference."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="measure and print JSON")
    p.add_argument("what", choices=sorted(BENCHES), help="; ".join(f"{k}: {v[1]}" for k, v in BENCHES.items()))
    p.add_argument("--n", type=int, default=None, help="sample count (bench-specific default)")
    p.add_argument("--cycles", type=int, default=None, help="soak: cycles to run (same as --n)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="also write the JSON to this file")
    p.add_argument(
        "--family",
        nargs="?",
        const="mixed",
        default=None,
        help="whole-bin: plan the shape family's meshes instead of the catalog (F[:A-B], default mixed:0-11)",
    )
    p.add_argument(
        "--commissioned",
        action="store_true",
        help="inspect: one commissioning cycle, then every view decided with and without its reference",
    )
    p.add_argument(
        "--seed-offset", type=int, default=0, help="inspect --commissioned: first cycle of this slice (0, 50, …)"
    )
    p.add_argument(
        "--merge", nargs="+", default=(), metavar="JSON", help="inspect --commissioned: merge slice JSONs, run nothing"
    )
    add_config_arguments(p)
    p.set_defaults(func=run)


def options_from_args(args: argparse.Namespace) -> BenchOptions:
    """The typed options of ``cellctl bench`` (``--cycles`` is the soak's name for ``--n``)."""
    return BenchOptions(
        n=args.cycles if args.cycles is not None else args.n,
        seed=args.seed,
        config=args.config,
        overrides=tuple(args.overrides),
        out=Path(args.out) if args.out else None,
        family=args.family,
        commissioned=getattr(args, "commissioned", False),
        first=getattr(args, "seed_offset", 0),
        merge=tuple(getattr(args, "merge", ())),
    )


def run(args: argparse.Namespace) -> int:
    opts = options_from_args(args)
    target = BENCHES[args.what][0]
    if args.what == "inspect" and (opts.commissioned or opts.merge):  # with and without commissioned references
        target = COMMISSIONED
    mod, fn = target.split(":")
    result = getattr(importlib.import_module(mod), fn)(opts)
    text = json.dumps(result, indent=2)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    sys.stdout.flush()
    return 0
