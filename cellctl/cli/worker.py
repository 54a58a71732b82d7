"""``cellctl worker <role> --backend <name>``: run one worker process.

Each role package ``cellctl.workers.<role>`` provides
``run_worker(cfg, backend, stop_event) -> None``, which builds the backend through the role's
factory, serves its ops until ``stop_event`` is set, and cleans up.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import signal
import sys
import threading

from cellctl.bus.keys import ROLES
from cellctl.cli import add_config_arguments, config_from_args

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("worker", help="run a worker process (robot, camera, classifier, planner)")
    p.add_argument("role", choices=ROLES)
    p.add_argument("--backend", default=None, help="backend name (default: from the config)")
    add_config_arguments(p)
    p.set_defaults(func=run)


def install_stop_signals(stop: threading.Event) -> None:
    """SIGTERM/SIGINT set ``stop`` so the process finishes what it is doing and exits cleanly."""

    def _handler(signum: int, _frame: object) -> None:
        log.info("signal %d: stopping", signum)
        stop.set()

    signal.signal(signal.SIGTERM, _handler)
    signal.signal(signal.SIGINT, _handler)


def run(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    # On a secured bus a worker is its role's principal: `run --with-workers` hands every child
    # the same config, and the ACL would refuse a worker's keys under any other name anyway.
    cfg.bus.principal = args.role
    module = importlib.import_module(f"cellctl.workers.{args.role}")
    stop = threading.Event()
    install_stop_signals(stop)
    module.run_worker(cfg, args.backend, stop)
    # The worker has closed its session and flushed its outputs. Skip interpreter
    # finalisation: native extensions (OMPL's nanobind, Embree) crash or report leaks while
    # tearing down, which would turn a clean stop into a non-zero exit.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)
