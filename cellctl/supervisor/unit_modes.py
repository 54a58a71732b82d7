"""PackML unit modes (ISA-TR88.00.02): which commands each mode offers, and when the mode may change.

=============  ====  ===========================================  ==========================================
mode           code  PackML commands offered                      use
=============  ====  ===========================================  ==========================================
production     1     the whole table of ``states/packml.yaml``    automatic inspection cycles
maintenance    2     the whole table                              test and data-collection cycles by staff
manual         3     the table less ``start``                     arm moved by hand; no automatic motion
=============  ====  ===========================================  ==========================================

A mode change is accepted only in Stopped, Idle or Aborted (TR88: the unit is at rest), is
refused anywhere else, and never changes the PackML state.
"""

from __future__ import annotations

from cellctl.messages import UnitMode

__all__ = ["MODE_CHANGE_STATES", "MODE_COMMANDS_REMOVED", "commands_in_mode", "mode_change_refusal"]

MODE_CHANGE_STATES = ("Stopped", "Idle", "Aborted")
"""The PackML states in which the unit mode may change."""

MODE_COMMANDS_REMOVED: dict[UnitMode, frozenset[str]] = {
    UnitMode.production: frozenset(),
    UnitMode.maintenance: frozenset(),
    UnitMode.manual: frozenset({"start"}),
}
"""PackML commands a mode does not offer (on top of what the state allows)."""


def commands_in_mode(allowed: list[str], mode: UnitMode) -> list[str]:
    """The state's allowed commands less those the mode removes (order kept)."""
    removed = MODE_COMMANDS_REMOVED[mode]
    return [c for c in allowed if c not in removed]


def mode_change_refusal(requested: UnitMode, state: str) -> str | None:
    """Why a change to ``requested`` is refused in ``state`` (top-level name), or None when allowed."""
    if state in MODE_CHANGE_STATES:
        return None
    return (
        f"unit mode change to {requested.name!r} not allowed in {state}; allowed in {', '.join(MODE_CHANGE_STATES)}"
    )
