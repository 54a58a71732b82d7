"""The deployment model: one Zenoh router per host, linked by explicit endpoints.

A plant runs one ``cellctl router`` per host (cell hosts, the compute host with the planner
pool, the plant host with the OPC UA gateway/HMI/MES side). Each reads a per-host YAML file
(``config/deploy/*.yaml``) parsed into :class:`RouterConfig`, which rejects unknown keys::

    host: cell1                                   # names the host in logs and the deployment
    listen: ["tcp/169.254.10.1:7447"]             # where other hosts' routers connect
    connect: ["tcp/127.0.0.1:7447", "tcp/169.254.20.1:7447"]   # the local daemon, peer routers
    lease_ms: 2000                                # a cut link is noticed within ~lease
    security_dir: null                            # `cellctl secure init` folder: auth, ACL, TLS
    pool: {cells: [cell1, cell2, cell3], jobs_dir: /var/lib/cellctl/pool}   # compute host only

On a cell host the daemon (``cellctl run``) stays the cell's own router on 127.0.0.1 with the
cell's ACL; the host router links it to the other hosts, so the cell's loopback contract does
not change when the cell joins a plant. Why one router per host: a shared router between
sites lost messages where one router per site linked to its peers did not (dora-rs), and a
router per host keeps each host's lease with its own links.

Multicast scouting and gossip are off: a router talks only to the endpoints it is given.
The effective configuration is logged at start (``ZENOH_CONFIG_OVERRIDE`` was once silently
ignored by a zenoh release: what the router really runs with must be visible).
"""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path
from typing import Any

import zenoh
from pydantic import Field, ValidationError, field_validator

from cellctl.bus.keys import check_cell_id
from cellctl.bus.security import apply_security
from cellctl.config import apply_overrides, explain_validation, safe_yaml_load
from cellctl.errors import ConfigError
from cellctl.strict_model import FrozenConfigModel as _Model

__all__ = [
    "PoolSection",
    "RouterConfig",
    "effective_config",
    "load_router_config",
    "open_router",
    "router_zenoh_config",
]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

_ENDPOINT = re.compile(r"^(tcp|tls|quic|udp)/(\[[0-9a-fA-F:]+\]|[A-Za-z0-9.-]+):\d{1,5}(#.*)?$")
_HOST = re.compile(r"^[a-z][a-z0-9-]{0,63}$")


class PoolSection(_Model):
    """The planner pool's job queue, run inside this router's process (compute host only)."""

    cells: list[str] = Field(min_length=1, description="cells whose planning jobs this pool takes")
    jobs_dir: Path = Field(description="job records (survive a restart of this router)")
    max_attempts: int = Field(default=2, ge=1, le=10, description="claims per job before it fails visibly")
    claim_wait_s: float = Field(default=1.0, gt=0, le=30, description="longest a worker's claim waits for a job")

    @field_validator("cells")
    @classmethod
    def _cells(cls, v: list[str]) -> list[str]:
        for c in v:
            check_cell_id(c)
        if len(set(v)) != len(v):
            raise ValueError(f"cells {v} name a cell twice")
        return v


class RouterConfig(_Model):
    """One host's router."""

    host: str = Field(description="host name in the deployment (lower-case letters, digits, '-')")
    listen: list[str] = Field(min_length=1)
    connect: list[str] = Field(default_factory=list)
    lease_ms: int = Field(default=2000, ge=500, le=60000, description="link lease; bounds cut-link detection")
    security_dir: Path | None = Field(default=None, description="`cellctl secure init` folder of this router")
    pool: PoolSection | None = None

    @field_validator("host")
    @classmethod
    def _host(cls, v: str) -> str:
        if not _HOST.match(v):
            raise ValueError(f"host {v!r} is invalid: expected lower-case letters, digits or '-'")
        return v

    @field_validator("listen", "connect")
    @classmethod
    def _endpoints(cls, v: list[str]) -> list[str]:
        for ep in v:
            if not _ENDPOINT.match(ep):
                raise ValueError(f"endpoint {ep!r} is invalid: expected PROTO/HOST:PORT with PROTO tcp, tls, quic, udp")
        return v


def load_router_config(path: Path | str, overrides: list[str] | None = None) -> RouterConfig:
    """Read a host's router YAML (relative paths resolve against the file's folder).

    Raises:
        ConfigError: the file is missing, not YAML, or a key is unknown or invalid (named).
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"router config {str(p)!r} does not exist; expected a YAML file (see config/deploy/)")
    data = safe_yaml_load(p.read_text(), str(p)) or {}
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected a mapping at the top level, got {type(data).__name__}")
    apply_overrides(data, overrides)
    try:
        rc = RouterConfig.model_validate(data)
    except ValidationError as err:
        raise ConfigError(explain_validation(err, RouterConfig, str(p))) from err
    root = p.resolve().parent
    updates: dict[str, Any] = {}
    if rc.security_dir is not None and not rc.security_dir.is_absolute():
        updates["security_dir"] = root / rc.security_dir
    if rc.pool is not None and not rc.pool.jobs_dir.is_absolute():
        updates["pool"] = rc.pool.model_copy(update={"jobs_dir": root / rc.pool.jobs_dir})
    return rc.model_copy(update=updates)


def router_zenoh_config(rc: RouterConfig) -> zenoh.Config:
    """The ``zenoh.Config`` of this host's router (security first, topology last, as the daemon does)."""
    conf = zenoh.Config()
    if rc.security_dir is not None:
        if not rc.security_dir.is_dir():
            raise ConfigError(f"router security_dir {str(rc.security_dir)!r} is not a folder (cellctl secure init)")
        apply_security(conf, rc.security_dir, "router", None)
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps(rc.listen))
    conf.insert_json5("connect/endpoints", json.dumps(rc.connect))
    # A peer router that is down (host booting, link cut) is retried for ever instead of
    # failing the start: hosts come up in any order.
    conf.insert_json5("connect/exit_on_failure", "false")
    conf.insert_json5("connect/timeout_ms", "-1")
    conf.insert_json5("connect/retry", '{"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    conf.insert_json5("transport/link/tx/lease", str(rc.lease_ms))
    return conf


_LOGGED_KEYS = (
    "mode",
    "listen/endpoints",
    "connect/endpoints",
    "scouting/multicast/enabled",
    "transport/link/tx/lease",
    "access_control/enabled",
)


def effective_config(conf: zenoh.Config) -> dict[str, Any]:
    """The settings that decide a router's topology and security, as the Zenoh config holds them."""
    out: dict[str, Any] = {}
    for key in _LOGGED_KEYS:
        try:
            out[key] = json.loads(conf.get_json(key))
        except Exception:  # zenoh raises its own error for an unset key
            out[key] = None
    return out


def open_router(rc: RouterConfig) -> zenoh.Session:
    """Open this host's router session and log its effective configuration.

    Raises:
        ConfigError: a listen endpoint cannot be bound (address not on this host, port in use).
    """
    conf = router_zenoh_config(rc)
    log.info("router %s effective config: %s", rc.host, json.dumps(effective_config(conf)))
    try:
        session = zenoh.open(conf)
    except Exception as err:
        raise ConfigError(
            f"router {rc.host!r} cannot listen on {rc.listen}: {err} (address not on this host, or port in use?)"
        ) from err
    return session
