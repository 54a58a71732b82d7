"""The PackML command topic: commands and unit-mode requests, the Start params, the Ack."""

from __future__ import annotations

import datetime as _dt
import enum
from collections.abc import Mapping
from typing import Any, Literal, cast, get_args

from pydantic import Field, field_validator, model_validator

from cellctl.messages.base import WireMessage, now_iso
from cellctl.surface import SURFACES, Surface


class PackMLCommand(enum.IntEnum):
    """PackML commands with their PackTags ``CntrlCmd`` codes."""

    reset = 1
    start = 2
    stop = 3
    hold = 4
    unhold = 5
    suspend = 6
    unsuspend = 7
    abort = 8
    clear = 9
    complete = 10


class UnitMode(enum.IntEnum):
    """PackML unit modes with their PackTags ``UnitModeCurrent`` / ``UnitModeRequested`` codes."""

    production = 1
    maintenance = 2
    manual = 3

    @property
    def wire_name(self) -> UnitModeName:
        """The name on the wire (``Command.unit_mode``, ``Ack``/``Status.unit_mode``)."""
        return cast(UnitModeName, self.name)


UnitModeName = Literal["production", "maintenance", "manual"]
CommandName = Literal["reset", "start", "stop", "hold", "unhold", "suspend", "unsuspend", "abort", "clear", "complete"]
"""A PackML command's name on the wire (``Command.command``)."""

MAX_USER_CHARS = 64
MAX_REQUEST_ID_CHARS = 128


def _strict_code(v: Any, field: str, allowed: str) -> Any:
    # Lax validation would read true as 1 and "2" as 2: a PLC sending those is broken.
    if isinstance(v, bool | str):
        raise ValueError(f"{field} must be an integer code {allowed}, got {type(v).__name__} {v!r}")
    return v


class Command(WireMessage):
    """A PackML command or a unit-mode change request from a PLC or operator on ``cell/<id>/cmd``.

    Exactly one of ``command`` (lower-case name), ``cntrl_cmd`` (PackTags code), ``unit_mode``
    (mode name), ``unit_mode_code`` (PackTags UnitMode code) or ``base_parked`` (a manual base's
    confirmation) is given.
    """

    type: Literal["cellctl/Command"] = "cellctl/Command"
    v: Literal[1] = 1
    command: CommandName | None = None
    cntrl_cmd: int | None = Field(default=None, description="PackTags CntrlCmd code 1..10")
    unit_mode: UnitModeName | None = Field(default=None, description="requested PackML unit mode")
    unit_mode_code: int | None = Field(default=None, description="PackTags UnitModeRequested code 1..3")
    base_parked: int | None = Field(
        default=None, ge=0, description="manual base: the operator/PLC confirms the base is parked at this station"
    )
    request_id: str | None = Field(default=None, max_length=MAX_REQUEST_ID_CHARS)
    user: str | None = Field(
        default=None, max_length=MAX_USER_CHARS, description="who sent it, e.g. 'hmi:alice' (printable)"
    )
    params: dict[str, Any] = Field(default_factory=dict)
    stamp: str | None = Field(
        default=None,
        description="when the sender sent it (ISO-8601 with a UTC offset); the supervisor refuses a stale one",
    )

    @field_validator("stamp")
    @classmethod
    def _aware_time(cls, v: str | None) -> str | None:
        if v is not None:
            try:
                t = _dt.datetime.fromisoformat(v)
            except ValueError:
                raise ValueError(f"stamp {v[:40]!r} is not an ISO-8601 time, e.g. {now_iso()!r}") from None
            if t.tzinfo is None:
                raise ValueError(f"stamp {v[:40]!r} has no UTC offset, e.g. {now_iso()!r}")
        return v

    @field_validator("cntrl_cmd", mode="before")
    @classmethod
    def _integer_code(cls, v: Any) -> Any:
        return _strict_code(v, "cntrl_cmd", "1..10")

    @field_validator("unit_mode_code", mode="before")
    @classmethod
    def _integer_mode(cls, v: Any) -> Any:
        return _strict_code(v, "unit_mode_code", "1..3")

    @field_validator("base_parked", mode="before")
    @classmethod
    def _station(cls, v: Any) -> Any:
        return _strict_code(v, "base_parked", "(a station number >= 0)")

    @field_validator("user")
    @classmethod
    def _printable(cls, v: str | None) -> str | None:
        if v is not None and not v.isprintable():
            raise ValueError(f"user {v[:MAX_USER_CHARS]!r} must be printable characters only")
        return v

    @model_validator(mode="after")
    def _one_command(self) -> Command:
        state_cmd = [f for f in ("command", "cntrl_cmd") if getattr(self, f) is not None]
        mode_cmd = [f for f in ("unit_mode", "unit_mode_code") if getattr(self, f) is not None]
        if self.base_parked is not None:
            if state_cmd or mode_cmd:
                raise ValueError(f"a base confirmation ('base_parked') comes alone, got it with {state_cmd + mode_cmd}")
            return self
        if mode_cmd and not state_cmd:
            if len(mode_cmd) == 2:
                raise ValueError("give exactly one of 'unit_mode' (a mode name) or 'unit_mode_code' (1..3), got both")
            if self.unit_mode_code is not None and self.unit_mode_code not in {m.value for m in UnitMode}:
                raise ValueError(
                    f"unit_mode_code {self.unit_mode_code!r} is unknown; expected one of "
                    + ", ".join(f"{m.value} {m.name}" for m in UnitMode)
                )
            return self
        if mode_cmd:
            raise ValueError(
                f"a command carries either a PackML command or a unit mode change, got both {state_cmd + mode_cmd}"
            )
        if len(state_cmd) != 1:
            raise ValueError(
                "give exactly one of 'command' (a PackML command name) or 'cntrl_cmd' (1..10), or a unit mode"
                f" change ('unit_mode' or 'unit_mode_code' 1..3); got {state_cmd or 'neither'}"
            )
        if self.cntrl_cmd is not None and self.cntrl_cmd not in {c.value for c in PackMLCommand}:
            raise ValueError(
                f"cntrl_cmd {self.cntrl_cmd!r} is unknown; expected one of "
                + ", ".join(f"{c.value} {c.name}" for c in PackMLCommand)
            )
        return self

    @property
    def requested_mode(self) -> UnitMode | None:
        """The unit mode this command asks for, whichever way it was given; None for a PackML command."""
        if self.unit_mode is not None:
            return UnitMode[self.unit_mode]
        if self.unit_mode_code is not None:
            return UnitMode(self.unit_mode_code)
        return None

    @property
    def name(self) -> str:
        """The command's lower-case PackML name, whichever way it was given ('unit_mode' for a mode change)."""
        if self.command is not None:
            return self.command
        if self.cntrl_cmd is not None:
            return PackMLCommand(self.cntrl_cmd).name
        if self.base_parked is not None:
            return "base_parked"
        return "unit_mode"


START_PARAM_NAMES = ("mode", "label", "surface", "perturb_m", "seed", "dataset")
StartMode = Literal["evaluate", "collect", "wash_and_verify", "commission"]
START_MODES: tuple[str, ...] = get_args(StartMode)
"""The Start param ``mode`` values (``commission``: added in v1, additive: older senders never send it)."""


class StartParams(WireMessage):
    """The params of a Start command (``Command.params``), as the supervisor checks them.

    On the wire they travel as a plain object inside the Command (no ``type``/``v`` there);
    this model is their schema, checked by :meth:`from_params` before the cycle starts.
    """

    type: Literal["cellctl/StartParams"] = "cellctl/StartParams"
    v: Literal[1] = 1
    mode: StartMode = Field(
        default="evaluate",
        description="evaluate: inspect; collect: store labelled images; wash_and_verify: inspect, wash the dirty "
        "regions, re-inspect them, up to wash.max_rounds rounds; commission (maintenance unit mode, a named user): "
        "the bin is declared clean, each view becomes the reference of its viewpoint and each surface's detector "
        "is enrolled from the views",
    )
    label: Literal["clean", "dirty"] | None = Field(default=None, description="collect mode: the class of this bin")
    surface: Surface | None = Field(
        default=None, description="surface to inspect; default planner.surface of the config"
    )
    perturb_m: float = Field(default=0.0, ge=0.0, le=0.1, description="collect mode: random camera offset (m)")
    seed: int = Field(default=0, ge=0, lt=2**63, description="seed of the perturbation")
    dataset: str | None = Field(
        default=None,
        max_length=64,
        description="collect mode: dataset folder name under classifier.dataset_dir (letters, digits, '.', '_', '-')",
    )

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> StartParams:
        """Check a Start command's params; raise ProtocolError naming the bad value."""
        from cellctl.classify.collect import DATASET_NAME
        from cellctl.errors import ProtocolError

        unknown = set(params) - set(START_PARAM_NAMES)
        if unknown:
            raise ProtocolError(f"unknown start params {sorted(unknown)}; allowed: {sorted(START_PARAM_NAMES)}")
        mode = params.get("mode", "evaluate")
        if mode not in START_MODES:
            known = ", ".join(map(repr, START_MODES[:-1])) + f" or {START_MODES[-1]!r}"
            raise ProtocolError(f"start param mode={mode!r:.80}; expected {known}")
        label = params.get("label")
        if mode == "collect" and label not in ("clean", "dirty"):
            raise ProtocolError(f"start param label={label!r}; collect mode needs label 'clean' or 'dirty'")
        if "surface" in params and params["surface"] not in SURFACES:
            expected = " or ".join(repr(s) for s in SURFACES)
            raise ProtocolError(f"start param surface={params['surface']!r}; expected {expected}")
        perturb = params.get("perturb_m", 0.0)
        if isinstance(perturb, bool) or not isinstance(perturb, int | float) or not 0 <= perturb <= 0.1:
            raise ProtocolError(f"start param perturb_m={perturb!r:.80}; expected a number in [0, 0.1] m")
        seed = params.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
            # numpy seeds the perturbation with it: a negative or huge seed would fail mid-cycle
            raise ProtocolError(f"start param seed={seed!r:.80}; expected an integer in [0, 2**63)")
        dataset = params.get("dataset")
        if "dataset" in params and not (isinstance(dataset, str) and DATASET_NAME.fullmatch(dataset)):
            raise ProtocolError(
                f"start param dataset={dataset!r:.80}; expected a dataset name (letters, digits, '.', '_', '-';"
                " at most 64, no path) stored under classifier.dataset_dir"
            )
        return cls(
            mode=mode,
            # evaluate mode ignores a label (accepted as before, never used)
            label=label if mode == "collect" else None,
            surface=params.get("surface"),
            perturb_m=float(perturb),
            seed=seed,
            dataset=dataset,
        )

    def as_params(self) -> dict[str, Any]:
        """The params as a Command carries them (only those set)."""
        return self.model_dump(exclude={"type", "v"}, exclude_none=True)


class Ack(WireMessage):
    """Reply to every command: accepted or not, with the reason and the state after it."""

    type: Literal["cellctl/Ack"] = "cellctl/Ack"
    v: Literal[1] = 1
    request_id: str | None
    command: str | None = None
    accepted: bool
    reason: str | None = None
    state: str
    user: str | None = Field(default=None, description="the Command's user, echoed")
    unit_mode: UnitModeName | None = Field(default=None, description="the unit mode after handling the command")
