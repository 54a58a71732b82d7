"""Zenoh endpoints (``tcp/127.0.0.1:7447``) checked when a config is read, not when a session opens.

``bus.listen: nonsense`` passed ``cellctl validate`` and ``run`` then died in Zenoh with a Rust
traceback (issue 32). :func:`check_endpoint` asks Zenoh's own parser first (``<protocol>/<address>``),
then what Zenoh accepts but no link can use: an unknown protocol, an IP link without ``host:port``,
a port above 65535.
"""

from __future__ import annotations

import json
import re

__all__ = ["PROTOCOLS", "check_endpoint"]

PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream", "unixpipe", "serial", "vsock")
"""The link protocols Zenoh ships (``<protocol>/<address>``)."""
_HOST_PORT = ("tcp", "udp", "tls", "quic", "ws")
_ADDRESS = re.compile(r"^(?:\[[0-9A-Fa-f:.%\w]+\]|[A-Za-z0-9.-]+):(\d{1,5})$")
"""``host:port`` or ``[ipv6]:port``, before any ``?metadata`` or ``#config``."""


def check_endpoint(endpoint: str) -> str:
    """Return ``endpoint`` if Zenoh can listen on or connect to it, else raise ValueError naming it.

    ValueError, not ConfigError: the config model reports it under its key (``bus.listen.0``).
    """
    import zenoh

    probe = zenoh.Config()
    try:
        probe.insert_json5("listen/endpoints", f"[{json.dumps(endpoint)}]")
    except zenoh.ZError:
        raise ValueError(
            f"endpoint {endpoint!r} is not a Zenoh endpoint: expected <protocol>/<address>, e.g. 'tcp/127.0.0.1:7447'"
        ) from None
    proto, _, rest = endpoint.partition("/")
    if proto not in PROTOCOLS:
        raise ValueError(f"endpoint {endpoint!r}: protocol {proto!r} is unknown; expected one of {list(PROTOCOLS)}")
    if proto in _HOST_PORT:
        address = re.split(r"[?#]", rest, maxsplit=1)[0]
        m = _ADDRESS.match(address)
        if m is None or int(m.group(1)) > 65535:
            raise ValueError(f"endpoint {endpoint!r}: expected {proto}/<host>:<port 0..65535>, got {address!r}")
    return endpoint
