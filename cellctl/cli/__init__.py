"""The ``cellctl`` command line: one module per verb group, each with ``register(subparsers)``.

A module's ``register`` adds its sub-commands and sets ``func(args) -> int`` on each parser.
Heavy libraries are imported inside the functions, so ``cellctl status`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from cellctl.errors import CellError

__all__ = ["main"]

# Verb modules, in the order they appear in --help. Add yours here.
VERB_MODULES = (
    "cellctl.cli.daemon",
    "cellctl.cli.operator",
    "cellctl.cli.info",
    "cellctl.cli.worker",
    "cellctl.cli.bench",
    "cellctl.cli.replay",
    "cellctl.cli.secure",
    "cellctl.cli.audit",
    "cellctl.cli.references",
    "cellctl.cli.demo",
    "cellctl.cli.classify",
    "cellctl.cli.vision",
    "cellctl.cli.sim",
    "cellctl.cli.geometry",
    "cellctl.cli.plan",
    "cellctl.cli.gateway",
    "cellctl.cli.hmi",
    "cellctl.cli.router",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="cellctl", description="Autonomous bin-inspection cell controller.")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    sub = parser.add_subparsers(dest="verb", metavar="COMMAND", required=True)
    for name in VERB_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def add_config_arguments(p: argparse.ArgumentParser) -> None:
    """``--config FILE`` and repeatable ``--set KEY.PATH=VALUE`` (shared by every verb)."""
    p.add_argument(
        "--config",
        "-c",
        default=None,
        help="cell config YAML (default: $CELLCTL_CONFIG, else ./config/cell.yaml, else the packaged defaults"
        " with outputs under ./logs)",
    )
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config key, e.g. --set supervisor.auto_reset=true (repeatable)",
    )


def resolve_config_args(args: argparse.Namespace) -> None:
    """Pin the config file a verb with ``--config`` reads (:func:`cellctl.config.resolve_config_path`)
    and say which on stderr; with the packaged defaults, outputs go under ``./logs``, not the install.

    Pinned once, so child processes (``run --with-workers``) and re-reads use the same file."""
    if not hasattr(args, "config") or not hasattr(args, "overrides"):
        return
    from pathlib import Path

    from cellctl.config import PACKAGED, output_overrides, resolve_config_path

    path, source = resolve_config_path(args.config)
    args.config, args.config_source = str(path), source
    if source == PACKAGED:
        args.overrides = [*output_overrides(Path.cwd() / "logs"), *args.overrides]
        source += "; outputs under ./logs"
    print(f"cellctl {args.verb}: config {path.resolve()} ({source})", file=sys.stderr)


def config_from_args(args: argparse.Namespace):  # CellConfig, imported lazily
    from cellctl.config import load_config

    return load_config(args.config, args.overrides)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    try:
        resolve_config_args(args)
        return int(args.func(args) or 0)
    except CellError as err:
        print(f"cellctl {args.verb}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
