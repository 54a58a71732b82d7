"""The HMI's own configuration (``config/hmi.yaml``): where it listens, who may log in, limits.

It is a separate file from the cell config because it holds the users' password hashes: it
lives on the HMI host only, with mode 0600, and the daemon never reads it. Users are added with
``cellctl hmi user add NAME --role operator`` (the password is read from the terminal and only
its scrypt hash is stored).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

from pydantic import Field, StrictBool, ValidationError, field_validator

from cellctl.config import apply_overrides, explain_validation, project_root, safe_yaml_load
from cellctl.errors import ConfigError
from cellctl.login_throttle import ThrottleConfig
from cellctl.strict_model import ConfigModel as _Model

__all__ = ["ROLES", "FoxgloveConfig", "HmiConfig", "HmiUser", "default_hmi_config_path", "load_hmi_config"]

ROLES = ("operator", "maintenance", "qa", "viewer")
"""Who may do what on the HMI: ``operator`` sends PackML commands, acknowledges alarms and reviews
views (confirms clean/dirty, releases a verdict); ``maintenance`` sends commands and may also change
the unit mode; ``qa`` reviews views and releases verdicts but sends no command; ``viewer`` logs in
and reads only (as without a login). Without a login the HMI is read-only."""

Role = Literal["operator", "maintenance", "qa", "viewer"]


class HmiUser(_Model):
    """One person who may log in. ``password_hash`` is ``scrypt$n$r$p$salt$hash`` (cellctl.hmi.auth)."""

    name: str = Field(pattern=r"^[a-z][a-z0-9_.-]{0,31}$", description="login name, also in Command.user")
    role: Role
    password_hash: str = Field(pattern=r"^(scrypt|pbkdf2_sha256)\$", description="never the password itself")


class FoxgloveConfig(_Model):
    """The optional live Foxglove view served by the HMI process (cellctl.hmi.foxglove_live)."""

    enabled: StrictBool = False
    host: str = "127.0.0.1"
    port: int = Field(default=8765, ge=1, le=65535)


class HmiConfig(_Model):
    """Everything ``cellctl hmi`` needs beyond the cell config."""

    host: str = Field(default="127.0.0.1", description="bind address; loopback unless a reverse proxy fronts it")
    port: int = Field(default=8080, ge=1, le=65535)
    users: list[HmiUser] = Field(default_factory=list, description="without users the HMI is read-only")
    session_idle_s: float = Field(default=1800.0, gt=0, le=7 * 86400, description="logout after this idle time")
    session_max_s: float = Field(default=12 * 3600.0, gt=0, le=30 * 86400, description="a shift, at most")
    cookie_secure: StrictBool = Field(default=False, description="set the cookie's Secure flag (behind HTTPS)")
    login: ThrottleConfig = Field(
        default_factory=ThrottleConfig,
        description="back-off of wrong passwords per (user, client address) and, looser, per address",
    )
    trusted_proxies: list[str] = Field(
        default_factory=list,
        description="addresses of reverse proxies whose X-Forwarded-For is believed; none by default (not even "
        "loopback): the client address is the socket's",
    )
    allowed_hosts: list[str] = Field(
        default_factory=list,
        description="host names the browser may use (Host header; DNS rebinding); empty: localhost, 127.0.0.1, ::1 "
        "and `host`",
    )
    header_timeout_s: float = Field(
        default=10.0, gt=0, le=300, description="a request's headers and body must arrive within this (slow clients)"
    )
    keepalive_s: int = Field(default=5, ge=1, le=300, description="an idle kept-alive connection is closed after")
    max_header_bytes: int = Field(default=16384, ge=1024, le=1 << 20, description="larger request heads get 400")
    max_connections: int = Field(default=200, ge=4, le=10000, description="beyond this, new requests get 503")
    command_timeout_s: float = Field(default=5.0, gt=0, le=60, description="wait this long for the Ack")
    stale_s: float = Field(default=3.0, gt=0, le=60, description="no Status for this long: 'cell unreachable'")
    events_kept: int = Field(default=500, ge=10, le=100000)
    max_query_bytes: int = Field(default=2048, ge=256, le=65536, description="longer query strings get 414")
    max_body_bytes: int = Field(default=16384, ge=1024, le=1 << 20, description="larger request bodies get 413")
    foxglove: FoxgloveConfig = Field(default_factory=FoxgloveConfig)

    @field_validator("users")
    @classmethod
    def _unique(cls, v: list[HmiUser]) -> list[HmiUser]:
        names = [u.name for u in v]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"user names must be unique; repeated: {dup}")
        return v

    def host_names(self) -> frozenset[str]:
        """The Host header names accepted (lower case, without the port)."""
        names = self.allowed_hosts or ["localhost", "127.0.0.1", "::1", self.host]
        return frozenset(n.lower().strip("[]") for n in names if n not in ("0.0.0.0", "::"))

    def user(self, name: str) -> HmiUser | None:
        return next((u for u in self.users if u.name == name), None)


def default_hmi_config_path() -> Path:
    return project_root() / "config" / "hmi.yaml"


def load_hmi_config(path: Path | str | None = None, overrides: list[str] | None = None) -> HmiConfig:
    """Load ``config/hmi.yaml`` (a missing default file means: defaults, no users).

    Raises:
        ConfigError: an explicitly named file is missing, or the file does not validate (the
            message names each key, its value and what is allowed).
    """
    p = Path(path) if path is not None else default_hmi_config_path()
    data: object = {}
    if p.is_file():
        data = safe_yaml_load(p.read_text(), str(p)) or {}
    elif path is not None:
        raise ConfigError(f"HMI config file {str(p)!r} does not exist; create it with `cellctl hmi user add`")
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: top level must be a mapping of HMI settings, got {type(data).__name__}")
    apply_overrides(data, overrides, "--hmi-set")
    try:
        return HmiConfig.model_validate(data)
    except ValidationError as err:
        raise ConfigError(explain_validation(err, HmiConfig, str(p))) from err


def save_hmi_config(cfg: HmiConfig, path: Path) -> Path:
    """Write the HMI config with mode 0600 from the first byte (it holds password hashes)."""
    import yaml

    text = "# cellctl HMI config (cellctl hmi user add/remove edits it; password hashes only, never passwords)\n"
    text += yaml.safe_dump(cfg.model_dump(mode="json", exclude_defaults=True), sort_keys=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.unlink(missing_ok=True)
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)
    return path
