"""The daemon's own sections: the bus, the supervisor with its worker timeouts, the recording."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, StrictBool, field_validator

from cellctl.bus.keys import ROLES
from cellctl.strict_model import ConfigModel as _Model


class BusConfig(_Model):
    """Zenoh endpoints. The daemon is a router listening on ``listen``; others are clients."""

    listen: list[str] = Field(
        default_factory=lambda: ["tcp/127.0.0.1:7447"], description="Zenoh endpoints the daemon's router listens on"
    )
    connect: list[str] = Field(
        default_factory=lambda: ["tcp/127.0.0.1:7447"], description="Zenoh endpoints workers and clients connect to"
    )
    lease_ms: int = Field(default=2000, ge=500, le=60000, description="link lease; bounds hang detection")
    zenoh_config: Path | None = Field(default=None, description="extra Zenoh json5 (tuning; loaded first)")
    multicast_scouting: StrictBool = Field(
        default=False, description="find peers by UDP multicast (off: only listed endpoints)"
    )
    security_dir: Path | None = Field(
        default=None, description="`cellctl secure init` folder: user/password auth, ACL, TLS (docs/security.md)"
    )
    principal: str | None = Field(
        default=None,
        pattern=r"^[a-z][a-z0-9_-]{0,63}$",
        description="who this client is on a secured bus; workers always use their role",
    )

    @field_validator("listen", "connect")
    @classmethod
    def _endpoints(cls, v: list[str]) -> list[str]:
        # here, not when the session opens: `validate` must refuse what `run` cannot use
        from cellctl.bus.endpoints import check_endpoint

        return [check_endpoint(ep) for ep in v]


class Timeouts(_Model):
    """Seconds to wait for each worker op before declaring the worker hung."""

    default: float = Field(default=5.0, gt=0, description="any worker op not named below")
    approach: float = Field(default=60.0, gt=0, description="the base parking at a station")
    move: float = Field(default=60.0, gt=0, description="one robot move to a viewpoint")
    capture: float = Field(default=10.0, gt=0, description="one camera capture")
    classify: float = Field(default=10.0, gt=0, description="one classifier request")
    plan_submit: float = Field(default=5.0, gt=0, description="the planner accepting a job")
    plan_wait: float = Field(default=600.0, gt=0, description="a planner job to finish (supervisor.wait_for_plan)")
    stop: float = Field(default=2.0, gt=0, description="the robot acknowledging a stop")
    wash: float = Field(default=120.0, gt=0, description="one wash request: the transit to a sweep and its passes")
    wash_plan: float = Field(default=180.0, gt=0, description="a wash plan from the planner worker")


class SupervisorConfig(_Model):
    status_period_s: float = Field(default=1.0, gt=0, le=60, description="Status published at least this often")
    timeouts: Timeouts = Field(default_factory=Timeouts)
    required_workers: list[str] = Field(
        default_factory=lambda: ["robot", "camera", "classifier", "planner"],
        description="roles that must be alive for Start to be accepted",
    )
    on_worker_lost: Literal["abort", "hold"] = Field(
        default="abort", description="a required worker lost during Execute: Abort, or Hold until it is back"
    )
    identify_attempts: int = Field(default=3, ge=1, le=10, description="bin identifications tried before aborting")
    identify_views: int = Field(
        default=1, ge=1, le=5, description="observation poses fused per identification (>1 when one view is not enough)"
    )
    wait_for_plan: StrictBool = Field(default=False, description="wait for the planner job instead of replan_required")
    auto_reset: StrictBool = Field(default=False, description="Complete → Resetting → Idle without a PLC Reset")
    max_command_bytes: int = Field(default=64 * 1024, ge=256, description="a larger Command payload is refused")
    spawn_workers: list[str] = Field(
        default_factory=lambda: ["robot", "camera", "classifier", "planner"],
        description="roles started as child processes by `cellctl run --with-workers` and `cellctl demo`",
    )

    @field_validator("required_workers", "spawn_workers")
    @classmethod
    def _roles(cls, v: list[str]) -> list[str]:
        bad = [r for r in v if r not in ROLES]
        if bad:
            raise ValueError(f"unknown worker roles {bad}; expected some of {list(ROLES)}")
        return v


class RecordingConfig(_Model):
    dir: Path = Field(default=Path("logs"), description="folder of the per-cycle MCAP logs")
    index: Path = Field(default=Path("logs/cells.db"), description="SQLite index of recorded cycles")
