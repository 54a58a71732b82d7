"""``cellctl gateway opcua``: the OPC UA PackML server for PLCs (docs/opcua.md), its own process."""

from __future__ import annotations

import argparse
import logging

from cellctl.cli import add_config_arguments, config_from_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("gateway", help="protocol gateways for the plant (OPC UA PackML)")
    kinds = p.add_subparsers(dest="gateway_kind", metavar="KIND", required=True)
    o = kinds.add_parser("opcua", help="serve the cell as an OPC UA PackML unit (OPC 30050 + PackTags)")
    o.add_argument("--gateway", default=None, metavar="FILE", help="gateway config YAML (docs/opcua.md)")
    o.add_argument(
        "--gw-set",
        dest="gw_overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a gateway key, e.g. --gw-set endpoint=opc.tcp://127.0.0.1:4841 (repeatable)",
    )
    add_config_arguments(o)
    o.set_defaults(func=run_opcua)


def run_opcua(args: argparse.Namespace) -> int:
    import asyncio
    import signal
    import sys

    from cellctl.gateway.opcua import OpcuaGateway, load_gateway_config

    # Zenoh callback, command and event-loop threads hand the GIL to each other on every command;
    # the default 5 ms switch interval would sit in StateCurrent's latency whenever one of them computes.
    sys.setswitchinterval(0.0005)
    cfg = config_from_args(args)
    gw_cfg = load_gateway_config(args.gateway, args.gw_overrides)
    # asyncua logs every request at INFO and each refused write at WARNING; our own log says what matters
    logging.getLogger("asyncua").setLevel(max(logging.ERROR, logging.getLogger().level))

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, stop.set)
        await OpcuaGateway(cfg, gw_cfg).serve(stop)

    asyncio.run(main())
    return 0
