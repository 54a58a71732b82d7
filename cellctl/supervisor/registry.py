"""The YAML machines checked against what this code provides: its steps, behaviours and their data flow."""

from __future__ import annotations

from pathlib import Path

from cellctl.supervisor.behaviours import BEHAVIOURS
from cellctl.supervisor.context import INITIAL_CONTEXT
from cellctl.supervisor.definition import CycleDefinition, PackMLDefinition, StepIO, load_cycle, load_packml
from cellctl.supervisor.steps import STEPS

__all__ = ["STEP_IO", "load_definitions"]

STEP_IO: dict[str, StepIO] = {k: StepIO(frozenset(v.READS), frozenset(v.WRITES)) for k, v in STEPS.items()}
"""Step name → the blackboard fields it reads and writes."""


def load_definitions(cfg_root: Path | None = None) -> tuple[PackMLDefinition, CycleDefinition]:
    """Load both YAML machines (``<cfg_root>/states/``, else the shipped ones), validated against this code.

    A config folder without a ``states/`` folder runs the shipped machines (a cell's own folder names
    only what it changes)."""
    root = cfg_root / "states" if cfg_root and (cfg_root / "states").is_dir() else None
    packml = load_packml(root / "packml.yaml" if root else None, BEHAVIOURS)
    cycle = load_cycle(
        root / "cycle.yaml" if root else None,
        {k: v.OUTCOMES for k, v in STEPS.items()},
        STEP_IO,
        INITIAL_CONTEXT,
    )
    return packml, cycle
