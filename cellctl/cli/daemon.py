"""``cellctl run``: the supervisor daemon."""

from __future__ import annotations

import argparse
import logging
import threading

from cellctl.cli import add_config_arguments
from cellctl.cli.worker import install_stop_signals

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run the supervisor daemon (starts in Stopped)")
    p.add_argument(
        "--with-workers", action="store_true", help="also start the configured sim workers as child processes"
    )
    add_config_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from cellctl.app import build_cell
    from cellctl.cli.info import load_run_config

    cfg = load_run_config(args.config, args.overrides)  # the checks `cellctl validate` runs
    stop = threading.Event()
    install_stop_signals(stop)
    with build_cell(cfg, with_workers=args.with_workers, config_file=args.config, overrides=args.overrides) as cell:
        log.warning(
            "cellctl daemon for cell %r listening on %s (state %s)",
            cfg.cell_id,
            cfg.bus.listen,
            cell.supervisor.top_state,
        )
        cell.run(stop)
    return 0
