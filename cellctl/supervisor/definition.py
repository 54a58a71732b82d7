"""Load and validate the declarative machines ``states/packml.yaml`` and ``states/cycle.yaml``.

The YAML says *what* the machine is; the code provides the behaviours and steps it names.
Loading fails at start, with the file and the offending name, when the YAML names a state,
behaviour, step or outcome the code does not provide, leaves an outcome unmapped, or leaves a
state unreachable — never in the middle of a cycle.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cellctl.config import project_root, safe_yaml_load
from cellctl.errors import ConfigError
from cellctl.messages import PackMLCommand

__all__ = [
    "CycleDefinition",
    "CycleState",
    "Exit",
    "PackMLDefinition",
    "PackMLState",
    "StepIO",
    "load_cycle",
    "load_packml",
    "mermaid",
]


class PackMLState(enum.IntEnum):
    """ISA-TR88 PackTags ``StateCurrent`` codes."""

    Undefined = 0
    Clearing = 1
    Stopped = 2
    Starting = 3
    Idle = 4
    Suspended = 5
    Execute = 6
    Stopping = 7
    Aborting = 8
    Aborted = 9
    Holding = 10
    Held = 11
    Unholding = 12
    Suspending = 13
    Unsuspending = 14
    Resetting = 15
    Completing = 16
    Complete = 17


class Exit(enum.StrEnum):
    """Ways the cycle leaves Execute."""

    complete = "complete"
    abort = "abort"
    hold = "hold"


@dataclass(frozen=True)
class StateSpec:
    name: str
    code: int
    acting: bool
    behaviour: str | None = None
    machine: str | None = None


@dataclass(frozen=True)
class PackMLDefinition:
    initial: str
    states: dict[str, StateSpec]
    commands: dict[str, dict[str, str]]  # command -> {source: dest}
    state_complete: dict[str, str]  # acting state -> dest

    def allowed_commands(self, state: str) -> list[str]:
        """PackML commands accepted in ``state`` (top-level name), in CntrlCmd order."""
        return [c.name for c in PackMLCommand if state in self.commands.get(c.name, {})]


@dataclass(frozen=True)
class CycleState:
    name: str
    step: str
    on: dict[str, str | Exit]  # outcome -> next state or exit


@dataclass(frozen=True)
class CycleDefinition:
    initial: str
    states: dict[str, CycleState] = field(default_factory=dict)


@dataclass(frozen=True)
class StepIO:
    """What a step reads from and writes to the cycle's blackboard (FlexBE input/output keys)."""

    reads: frozenset[str] = frozenset()
    writes: frozenset[str] = frozenset()


def _check_data_flow(
    path: Path, initial: str, states: dict[str, CycleState], io: Mapping[str, StepIO], provided: frozenset[str]
) -> None:
    """Refuse a state whose step reads a field that is not written on every path to it.

    A forward must-analysis over the cycle graph: what is surely set on entering a state is what
    the initial context provides (for the initial state) intersected over every edge into it.
    """
    preds: dict[str, list[str]] = {name: [] for name in states}
    for st in states.values():
        for dest in st.on.values():
            if not isinstance(dest, Exit):
                preds[dest].append(st.name)
    every = provided.union(*(x.writes for x in io.values()))
    surely: dict[str, frozenset[str]] = {name: every for name in states}
    surely[initial] = provided
    changed = True
    while changed:
        changed = False
        for name in states:
            if name == initial:
                continue  # its first entry has only the initial context
            new = frozenset.intersection(every, *(surely[p] | io[states[p].step].writes for p in preds[name]))
            if new != surely[name]:
                surely[name], changed = new, True
    for name, st in states.items():
        missing = io[st.step].reads - surely[name]
        if missing:
            raise ConfigError(
                f"{path}: states.{name}: step {st.step!r} reads {sorted(missing)}, which no step writes on every"
                f" path from {initial!r} to it (nor does the cycle's initial context provide it)"
            )


def _read(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise ConfigError(f"state machine file {str(path)!r} does not exist")
    data = safe_yaml_load(path.read_text(), str(path))
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level, got {type(data).__name__}")
    return data


def _need(d: Mapping[str, Any], key: str, where: str) -> Any:
    if key not in d:
        raise ConfigError(f"{where}: missing key {key!r}")
    return d[key]


def load_packml(path: Path | None = None, behaviours: Iterable[str] = ()) -> PackMLDefinition:
    """Load ``states/packml.yaml`` and check it against TR88 and the provided behaviours.

    Raises:
        ConfigError: unknown/missing state, wrong code, unknown behaviour or command,
            a transition the PackML table does not allow, an acting state without State Complete.
    """
    path = path or project_root() / "states" / "packml.yaml"
    data = _read(path)
    known_behaviours = set(behaviours)
    unknown_top = set(data) - {"initial", "states", "commands", "state_complete"}
    if unknown_top:
        raise ConfigError(
            f"{path}: unknown keys {sorted(unknown_top)}; allowed: initial, states, commands, state_complete"
        )
    states: dict[str, StateSpec] = {}
    for i, s in enumerate(_need(data, "states", str(path))):
        where = f"{path}: states[{i}]"
        if not isinstance(s, dict):
            raise ConfigError(f"{where}: expected a mapping, got {s!r}")
        extra = set(s) - {"name", "code", "kind", "behaviour", "machine"}
        if extra:
            raise ConfigError(f"{where}: unknown keys {sorted(extra)}")
        name = _need(s, "name", where)
        if name not in PackMLState.__members__ or name == "Undefined":
            raise ConfigError(
                f"{where}: state {name!r} is not a TR88 state; expected one of {list(PackMLState.__members__)[1:]}"
            )
        code = _need(s, "code", where)
        if code != PackMLState[name].value:
            raise ConfigError(f"{where}: state {name!r} has code {code!r}; TR88 says {PackMLState[name].value}")
        kind = _need(s, "kind", where)
        if kind not in ("acting", "wait"):
            raise ConfigError(f"{where}: kind {kind!r} must be 'acting' or 'wait'")
        behaviour = s.get("behaviour")
        if behaviour is not None and behaviour not in known_behaviours:
            raise ConfigError(
                f"{where}: behaviour {behaviour!r} of state {name!r} is not provided by the code; "
                f"known behaviours: {sorted(known_behaviours)}"
            )
        machine = s.get("machine")
        if machine is not None and machine != "cycle":
            raise ConfigError(f"{where}: nested machine {machine!r} is unknown; only 'cycle' exists")
        states[name] = StateSpec(name, code, kind == "acting", behaviour, machine)
    missing = [s.name for s in PackMLState if s.name != "Undefined" and s.name not in states]
    if missing:
        raise ConfigError(f"{path}: TR88 states missing: {missing}")

    commands: dict[str, dict[str, str]] = {}
    for i, c in enumerate(_need(data, "commands", str(path))):
        where = f"{path}: commands[{i}]"
        name = _need(c, "command", where)
        if name not in PackMLCommand.__members__:
            raise ConfigError(
                f"{where}: command {name!r} is unknown; expected one of {list(PackMLCommand.__members__)}"
            )
        dest = _need(c, "dest", where)
        srcs = _need(c, "source", where)
        srcs = [srcs] if isinstance(srcs, str) else list(srcs)
        for st in [dest, *srcs]:
            if st not in states:
                raise ConfigError(f"{where}: state {st!r} is not defined in states")
        table = commands.setdefault(name, {})
        for src in srcs:
            if src in table:
                raise ConfigError(f"{where}: command {name!r} from {src!r} is defined twice")
            table[src] = dest

    state_complete = dict(_need(data, "state_complete", str(path)))
    for src, dest in state_complete.items():
        if src not in states or dest not in states:
            raise ConfigError(f"{path}: state_complete {src!r} -> {dest!r} names an undefined state")
        if not states[src].acting:
            raise ConfigError(f"{path}: state_complete from wait state {src!r}; only acting states complete")
    for s in states.values():
        if s.acting and s.name not in state_complete:
            raise ConfigError(f"{path}: acting state {s.name!r} has no state_complete destination")
        if s.acting and s.behaviour is None and s.machine is None:
            raise ConfigError(f"{path}: acting state {s.name!r} names neither a behaviour nor a machine")

    initial = _need(data, "initial", str(path))
    if initial not in ("Stopped", "Aborted"):
        raise ConfigError(f"{path}: initial state {initial!r}; TR88/OPC UA allow only 'Stopped' or 'Aborted'")
    return PackMLDefinition(initial, states, commands, state_complete)


def load_cycle(
    path: Path | None = None,
    steps: Mapping[str, Iterable[str]] | None = None,
    io: Mapping[str, StepIO] | None = None,
    initial_context: Iterable[str] = (),
) -> CycleDefinition:
    """Load ``states/cycle.yaml`` and check every step and outcome against the code.

    Args:
        steps: step name → its declared outcomes, as the code provides them.
        io: step name → the blackboard fields it reads and writes; when given, every state's
            step must find what it reads written on every path from ``initial``.
        initial_context: the fields every cycle starts with set.

    Raises:
        ConfigError: unknown step, an outcome the step does not declare, an outcome of the step
            left unmapped, an unknown destination, a state unreachable from ``initial``,
            a state name with ``.`` (the nesting separator), or a step reading a field that
            no step writes before it.
    """
    path = path or project_root() / "states" / "cycle.yaml"
    data = _read(path)
    provided = {k: set(v) for k, v in (steps or {}).items()}
    raw_states = _need(data, "states", str(path))
    if not isinstance(raw_states, dict) or not raw_states:
        raise ConfigError(f"{path}: 'states' must be a non-empty mapping of state name to definition")
    states: dict[str, CycleState] = {}
    for name, s in raw_states.items():
        where = f"{path}: states.{name}"
        if not isinstance(name, str) or not name or "." in name or name[0].isupper():
            raise ConfigError(f"{where}: state name {name!r} must be lower-case and contain no '.'")
        extra = set(s) - {"step", "on"}
        if extra:
            raise ConfigError(f"{where}: unknown keys {sorted(extra)}; allowed: step, on")
        step = _need(s, "step", where)
        if step not in provided:
            raise ConfigError(f"{where}: step {step!r} is not provided by the code; known steps: {sorted(provided)}")
        on: dict[str, str | Exit] = {}
        for outcome, dest in (_need(s, "on", where) or {}).items():
            if outcome not in provided[step]:
                raise ConfigError(
                    f"{where}: outcome {outcome!r} is not declared by step {step!r}; "
                    f"it declares {sorted(provided[step])}"
                )
            if isinstance(dest, dict):
                if set(dest) != {"exit"} or dest["exit"] not in Exit.__members__:
                    raise ConfigError(f"{where}.on.{outcome}: {dest!r} must be {{exit: complete|abort|hold}}")
                on[outcome] = Exit(dest["exit"])
            else:
                on[outcome] = str(dest)
        unmapped = provided[step] - set(on)
        if unmapped:
            raise ConfigError(f"{where}: outcomes {sorted(unmapped)} of step {step!r} are not mapped in 'on'")
        states[name] = CycleState(name, step, on)
    for st in states.values():
        for outcome, dest in st.on.items():
            if not isinstance(dest, Exit) and dest not in states:
                raise ConfigError(f"{path}: states.{st.name}.on.{outcome} goes to unknown state {dest!r}")
    initial = _need(data, "initial", str(path))
    if initial not in states:
        raise ConfigError(f"{path}: initial state {initial!r} is not defined")
    seen, todo = {initial}, [initial]
    while todo:
        for dest in states[todo.pop()].on.values():
            if not isinstance(dest, Exit) and dest not in seen:
                seen.add(dest)
                todo.append(dest)
    unreachable = sorted(set(states) - seen)
    if unreachable:
        raise ConfigError(f"{path}: states {unreachable} cannot be reached from {initial!r}")
    if io is not None:
        _check_data_flow(path, initial, states, io, frozenset(initial_context))
    return CycleDefinition(initial, states)


def mermaid(packml: PackMLDefinition, cycle: CycleDefinition) -> str:
    """Both machines as one Mermaid ``stateDiagram-v2`` (Execute drawn as a composite state)."""
    lines = ["stateDiagram-v2", f"    [*] --> {packml.initial}"]
    for cmd, table in packml.commands.items():
        for src, dest in table.items():
            lines.append(f"    {src} --> {dest}: {cmd}")
    for src, dest in packml.state_complete.items():
        lines.append(f"    {src} --> {dest}: SC")
    lines.append("    state Execute {")
    lines.append(f"        [*] --> {cycle.initial}")
    for st in cycle.states.values():
        for outcome, dest in st.on.items():
            if isinstance(dest, Exit):
                lines.append(f"        {st.name} --> [*]: {outcome} / {dest.value}")
            else:
                lines.append(f"        {st.name} --> {dest}: {outcome}")
    lines.append("    }")
    return "\n".join(lines) + "\n"
