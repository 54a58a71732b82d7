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

A Start's ``mode`` param may also need a unit mode: ``commission`` (the bin declared clean becomes
the reference of every viewpoint and re-enrolls the detectors) is staff work, refused in production
(a PLC's automatic Start must never re-teach what clean looks like) and in manual (no Start at all).
"""

from __future__ import annotations

from cellctl.messages import UnitMode

__all__ = [
    "MODE_CHANGE_STATES",
    "MODE_COMMANDS_REMOVED",
    "START_MODE_UNIT_MODES",
    "commands_in_mode",
    "mode_change_refusal",
    "start_mode_refusal",
]

MODE_CHANGE_STATES = ("Stopped", "Idle", "Aborted")
"""The PackML states in which the unit mode may change."""

MODE_COMMANDS_REMOVED: dict[UnitMode, frozenset[str]] = {
    UnitMode.production: frozenset(),
    UnitMode.maintenance: frozenset(),
    UnitMode.manual: frozenset({"start"}),
}
"""PackML commands a mode does not offer (on top of what the state allows)."""

START_MODE_UNIT_MODES: dict[str, frozenset[UnitMode]] = {"commission": frozenset({UnitMode.maintenance})}
"""Start ``mode`` params allowed only in some unit modes (absent: every mode that offers Start)."""


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


def start_mode_refusal(start_mode: str, mode: UnitMode) -> str | None:
    """Why a Start with param ``mode=start_mode`` is refused in unit mode ``mode``, or None when allowed."""
    allowed = START_MODE_UNIT_MODES.get(start_mode)
    if allowed is None or mode in allowed:
        return None
    names = ", ".join(sorted(m.name for m in allowed))
    return f"start mode {start_mode!r} is not allowed in unit mode {mode.name!r}; allowed in: {names}"
