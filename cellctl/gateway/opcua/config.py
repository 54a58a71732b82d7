"""The OPC UA gateway's configuration: a typed model that rejects unknown keys.

It lives beside the cell config (which names the bus and the cell): ``cellctl gateway opcua
--gateway FILE --gw-set KEY=VALUE``. Every default is the safe one for a laptop: loopback
endpoint, security None, anonymous read-only.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal
from urllib.parse import urlparse

from pydantic import BaseModel, ConfigDict, Field, StrictBool, ValidationError, field_validator

from cellctl.bus.keys import check_cell_id
from cellctl.config import apply_overrides, explain_validation, safe_yaml_load
from cellctl.errors import ConfigError
from cellctl.login_throttle import ThrottleConfig

__all__ = ["DEFAULT_ENDPOINT", "OpcuaConfig", "SecurityMode", "load_gateway_config"]

DEFAULT_ENDPOINT = "opc.tcp://127.0.0.1:4840"

SecurityMode = Literal["none", "sign", "sign_encrypt"]
"""Message security modes offered, each with policy Basic256Sha256 (``none``: no security)."""


class OpcuaConfig(BaseModel):
    """What the gateway serves and who may command through it."""

    model_config = ConfigDict(extra="forbid")

    endpoint: str = Field(default=DEFAULT_ENDPOINT, description="opc.tcp://HOST:PORT the server listens on")
    cells: list[str] = Field(default_factory=list, description="cell ids served (default: the cell config's id)")
    security: list[SecurityMode] = Field(
        default_factory=lambda: ["none"], min_length=1, description="offered modes; production: [sign_encrypt]"
    )
    certificate: Path | None = Field(
        default=None, description="server certificate (PEM/DER); default <bus.security_dir>/opcua/server.pem"
    )
    private_key: Path | None = Field(
        default=None, description="its private key; default <bus.security_dir>/opcua/server.key"
    )
    trusted_clients: Path | None = Field(
        default=None, description="folder of trusted client certificates; unset: any client certificate is accepted"
    )
    allow_anonymous: StrictBool = Field(default=True, description="anonymous sessions may browse, read, subscribe")
    users_file: Path | None = Field(
        default=None, description="user:password per line; these users may write and call (like bus principals)"
    )
    bus_principals: StrictBool = Field(
        default=True,
        description="accept the secured bus' principals (bus.security_dir/passwords); "
        "those with the command grant may command",
    )
    principal: str = Field(default="plc", description="the bus principal the gateway itself connects as")
    command_timeout_s: float = Field(default=5.0, gt=0, le=60, description="wait for the daemon's Ack")
    stale_after_s: float = Field(
        default=3.5, gt=0, le=600, description="no Status for this long: StateCurrent 0 (daemon down)"
    )
    reconnect_s: float = Field(default=1.0, gt=0, le=60, description="retry period while the bus is unreachable")
    login: ThrottleConfig = Field(
        default_factory=ThrottleConfig, description="back-off of wrong passwords per (user, address) and per address"
    )

    @field_validator("endpoint")
    @classmethod
    def _endpoint(cls, v: str) -> str:
        u = urlparse(v)
        if u.scheme != "opc.tcp" or not u.hostname or u.port is None:
            raise ValueError(f"endpoint {v!r} is invalid: expected opc.tcp://HOST:PORT, e.g. {DEFAULT_ENDPOINT}")
        return v

    @field_validator("cells")
    @classmethod
    def _cells(cls, v: list[str]) -> list[str]:
        for c in v:
            try:
                check_cell_id(c)
            except ConfigError as err:
                raise ValueError(str(err)) from None
        if len(set(v)) != len(v):
            raise ValueError(f"cells {v} name a cell twice")
        return v

    @property
    def host(self) -> str:
        return urlparse(self.endpoint).hostname or ""

    @property
    def port(self) -> int:
        return int(urlparse(self.endpoint).port or 0)


def load_gateway_config(path: Path | str | None = None, overrides: list[str] | None = None) -> OpcuaConfig:
    """The gateway config from an optional YAML file plus ``KEY=VALUE`` overrides.

    Raises:
        ConfigError: the file is missing or not YAML, or a key is unknown or invalid (named with its value).
    """
    data: dict = {}
    source = "<gateway defaults>"
    if path is not None:
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"gateway config file {str(p)!r} does not exist")
        source = str(p)
        loaded = safe_yaml_load(p.read_text(), source)
        if loaded is not None and not isinstance(loaded, dict):
            raise ConfigError(f"{p}: top level must be a mapping of gateway keys, got {type(loaded).__name__}")
        data = dict(loaded or {})
    apply_overrides(data, overrides, "--gw-set")
    try:
        return OpcuaConfig.model_validate(data)
    except ValidationError as err:
        raise ConfigError(explain_validation(err, OpcuaConfig, source)) from err
