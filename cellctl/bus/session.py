"""Zenoh session factory: router in the daemon, client everywhere else.

Multicast scouting is off: peers find each other only through the configured endpoints,
so a cell never talks to a stranger on the plant network by accident.
"""

from __future__ import annotations

import json
import logging
import socket
from pathlib import Path
from typing import Literal

import zenoh

from cellctl.bus.security import apply_security
from cellctl.config import BusConfig, CellConfig
from cellctl.errors import ConfigError

__all__ = ["make_zenoh_config", "open_session", "private_bus_overrides"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

Mode = Literal["router", "client", "peer"]


def make_zenoh_config(bus: BusConfig, mode: Mode, root: object = None) -> zenoh.Config:
    """Build a ``zenoh.Config`` for ``mode`` from the bus section.

    A ``bus.zenoh_config`` file is loaded first; a ``bus.security_dir`` deployment then sets
    auth, access control and TLS (as the router, or as client ``bus.principal``); mode,
    endpoints, scouting and lease are set last from the bus section, so no file can silently
    re-enable multicast scouting.

    Raises:
        ConfigError: a file is missing or does not parse, or a client on a secured bus has no
            (known) principal.
    """
    if bus.zenoh_config is not None:
        path = _resolve(bus.zenoh_config, root)
        try:
            conf = zenoh.Config.from_file(str(path))
        except Exception as err:  # zenoh raises its own ZError for any parse problem
            raise ConfigError(f"bus.zenoh_config {str(path)!r} cannot be loaded: {err}") from err
    else:
        conf = zenoh.Config()
    if bus.security_dir is not None:
        apply_security(conf, _resolve(bus.security_dir, root), mode, bus.principal)
    conf.insert_json5("mode", json.dumps(mode))
    if mode == "router":
        conf.insert_json5("listen/endpoints", json.dumps(bus.listen))
        conf.insert_json5("connect/endpoints", "[]")
    else:
        conf.insert_json5("connect/endpoints", json.dumps(bus.connect))
        conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", json.dumps(bus.multicast_scouting))
    conf.insert_json5("scouting/gossip/enabled", "false")
    conf.insert_json5("transport/link/tx/lease", str(bus.lease_ms))
    return conf


def _resolve(path: Path, root: object) -> Path:
    return root / path if root is not None and not path.is_absolute() else path  # type: ignore[operator]


def _refused_by_router(endpoints: list[str]) -> bool:
    """True if some tcp/tls endpoint accepts a TCP connection: the router is there, so it refused the session."""
    for ep in endpoints:
        proto, _, addr = ep.partition("/")
        host, _, port = addr.split("#", 1)[0].rpartition(":")
        if proto not in ("tcp", "tls") or not port.isdigit():
            continue
        try:
            socket.create_connection((host.strip("[]"), int(port)), timeout=0.5).close()
            return True
        except OSError:
            continue
    return False


def open_session(cfg: CellConfig, mode: Mode) -> zenoh.Session:
    """Open a Zenoh session for this cell.

    Raises:
        ConfigError: the endpoints cannot be bound/connected (port in use, no router).
    """
    conf = make_zenoh_config(cfg.bus, mode, cfg.root)
    endpoints = cfg.bus.listen if mode == "router" else cfg.bus.connect
    try:
        session = zenoh.open(conf)
    except Exception as err:
        if mode == "router":
            hint = "is another daemon already listening there?"
        elif cfg.bus.security_dir is not None and _refused_by_router(endpoints):
            hint = (
                f"the router is reachable but refused principal {cfg.bus.principal!r}: wrong password, a principal "
                f"the router does not know, or a certificate its CA did not sign (see docs/security.md)"
            )
        else:
            hint = "is the daemon running?"
        raise ConfigError(f"cannot open a Zenoh {mode} session on {endpoints}: {err} ({hint})") from err
    log.debug("zenoh %s session %s on %s", mode, session.info.zid(), endpoints)
    return session


def private_bus_overrides() -> list[str]:
    """``--set`` overrides that put a throw-away cell's bus on a free loopback port."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    ep = f'["tcp/127.0.0.1:{port}"]'
    return [f"bus.listen={ep}", f"bus.connect={ep}"]
