"""The ``transitions`` machine built from both YAML definitions: PackML with the cycle nested in Execute."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from transitions.extensions.nesting import HierarchicalMachine, NestedState

from cellctl.supervisor.definition import CycleDefinition, Exit, PackMLDefinition

__all__ = ["CellModel", "build_machine"]


class _CellState(NestedState):
    # '_' is transitions' default separator; our state names use it (checking_cache).
    separator = "."


class _CellMachine(HierarchicalMachine):
    state_cls = _CellState


class CellModel:
    """The object ``transitions`` drives; it holds only ``state`` (e.g. ``Execute.scanning``)."""

    state: str
    trigger: Callable[[str], bool]  # added by transitions: fire a trigger by name

    @property
    def top(self) -> str:
        """The PackML state, e.g. ``Execute``."""
        return self.state.split(".", 1)[0]

    @property
    def step(self) -> str | None:
        """The cycle state inside Execute, else None."""
        parts = self.state.split(".", 1)
        return parts[1] if len(parts) == 2 else None


def build_machine(
    packml: PackMLDefinition,
    cycle: CycleDefinition,
    model: CellModel,
    saved_step: Callable[[], str | None],
    after_state_change: Callable[[], None],
) -> HierarchicalMachine:
    """Triggers: every PackML command, ``sc`` (State Complete) and ``step_<outcome>`` per cycle state.

    Unholding/Unsuspending resume the cycle state ``saved_step()`` names (transitions has no
    history states), else the cycle's initial state.
    """
    children = list(cycle.states)
    states: list[Any] = []
    for spec in packml.states.values():
        if spec.machine == "cycle":
            states.append({"name": spec.name, "children": children, "initial": cycle.initial})
        else:
            states.append(spec.name)
    transitions: list[dict[str, Any]] = []
    for cmd, table in packml.commands.items():
        for src, dest in table.items():
            transitions.append({"trigger": cmd, "source": src, "dest": dest})
    for src, dest in packml.state_complete.items():
        if dest == "Execute" and src != "Starting":
            for child in children:
                transitions.append(
                    {
                        "trigger": "sc",
                        "source": src,
                        "dest": f"Execute.{child}",
                        "conditions": (lambda c=child: saved_step() == c),
                    }
                )
            transitions.append({"trigger": "sc", "source": src, "dest": f"Execute.{cycle.initial}"})
        else:
            transitions.append({"trigger": "sc", "source": src, "dest": dest})
    exit_dest = {Exit.complete: "Completing", Exit.abort: "Aborting", Exit.hold: "Holding"}
    for st in cycle.states.values():
        for outcome, dest in st.on.items():
            target = exit_dest[dest] if isinstance(dest, Exit) else f"Execute.{dest}"
            transitions.append({"trigger": f"step_{outcome}", "source": f"Execute.{st.name}", "dest": target})
    return _CellMachine(
        model=model,
        states=states,
        transitions=transitions,
        initial=packml.initial,
        auto_transitions=False,
        queued=True,
        after_state_change=after_state_change,
    )
