"""Zenoh session factory: router in the daemon, client everywhere else.

Multicast scouting is off: peers find each other only through the configured endpoints,
so a cell never talks to a stranger on the plant network by accident.
"""

from __future__ import annotations

import json
import logging
from typing import Literal

import zenoh

from cellctl.config import BusConfig, CellConfig
from cellctl.errors import ConfigError

__all__ = ["make_zenoh_config", "open_session"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

Mode = Literal["router", "client", "peer"]


def make_zenoh_config(bus: BusConfig, mode: Mode, root: object = None) -> zenoh.Config:
    """Build a ``zenoh.Config`` for ``mode`` from the bus section.

    A ``bus.zenoh_config`` file (auth, access control, TLS) is loaded first; mode, endpoints,
    scouting and lease are then set from the bus section, so the file cannot silently
    re-enable multicast scouting.
    """
    if bus.zenoh_config is not None:
        path = bus.zenoh_config
        if root is not None and not path.is_absolute():
            path = root / path  # type: ignore[operator]
        try:
            conf = zenoh.Config.from_file(str(path))
        except Exception as err:  # zenoh raises its own ZError for any parse problem
            raise ConfigError(f"bus.zenoh_config {str(path)!r} cannot be loaded: {err}") from err
    else:
        conf = zenoh.Config()
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
        hint = "is another daemon already listening there?" if mode == "router" else "is the daemon running?"
        raise ConfigError(f"cannot open a Zenoh {mode} session on {endpoints}: {err} ({hint})") from err
    log.debug("zenoh %s session %s on %s", mode, session.info.zid(), endpoints)
    return session
