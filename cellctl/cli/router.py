"""``cellctl router HOST.yaml``: this host's Zenoh router (and, on the compute host, the planner pool's queue).

One router per host, linked to its peers by explicit endpoints (docs/deploy/README.md). The
per-host file is a :class:`~cellctl.bus.router.RouterConfig`; ``--check`` validates it and
prints the effective Zenoh settings without opening anything.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading

log = logging.getLogger(__name__)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("router", help="run this host's Zenoh router (per-host config, see config/deploy/)")
    p.add_argument("config", help="the host's router YAML (config/deploy/*.yaml)")
    p.add_argument(
        "--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE", help="override a key (repeatable)"
    )
    p.add_argument("--check", action="store_true", help="validate and print the effective settings, then exit")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from cellctl.bus.router import effective_config, load_router_config, open_router, router_zenoh_config
    from cellctl.cli.worker import install_stop_signals

    rc = load_router_config(args.config, args.overrides)
    if args.check:
        print(json.dumps({"host": rc.host, **effective_config(router_zenoh_config(rc))}, indent=2))
        return 0
    stop = threading.Event()
    install_stop_signals(stop)
    session = open_router(rc)
    pool = None
    try:
        if rc.pool is not None:
            from cellctl.workers.planner.pool import JobQueue

            pool = JobQueue(
                session, rc.pool.cells, rc.pool.jobs_dir, rc.pool.max_attempts, rc.pool.claim_wait_s
            ).start()
        # One line on stderr that harnesses wait for (the daemon prints the same kind).
        print(
            f"cellctl router {rc.host} listening on {rc.listen}, connecting {rc.connect}"
            + (f", planner pool for {rc.pool.cells}" if rc.pool else ""),
            file=sys.stderr,
            flush=True,
        )
        stop.wait()
    finally:
        if pool is not None:
            pool.close()
        session.close()
    return 0
