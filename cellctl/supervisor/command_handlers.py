"""Commands that move no PackML state, each handled by a function registered under the command's name.

The dispatcher looks a command's name up here before firing it as a trigger (:meth:`Supervisor._apply`);
a handler does its work or raises :class:`~cellctl.errors.CellError`, which refuses the command with its
message. Adding such a command is one registered function, not a branch in the supervisor.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from cellctl.errors import CellError
from cellctl.supervisor.commands import Accepted

if TYPE_CHECKING:
    from cellctl.supervisor.cycles import CycleKeeper

__all__ = ["HANDLERS", "Handler", "handles"]

Handler = Callable[["CycleKeeper", Accepted], str]
"""``(cycles, command) -> the event text`` of a command done; raises CellError to refuse it."""

HANDLERS: dict[str, Handler] = {}
"""Command name -> its handler."""


def handles(name: str) -> Callable[[Handler], Handler]:
    """Register the decorated function as the handler of command ``name`` (once)."""

    def register(fn: Handler) -> Handler:
        if name in HANDLERS:
            raise ValueError(f"command {name!r} already has a handler: {HANDLERS[name].__name__}")
        HANDLERS[name] = fn
        return fn

    return register


@handles("base_parked")
def confirm_base(cycles: CycleKeeper, checked: Accepted) -> str:
    """A manual base's ``base_parked`` confirmation: wakes the approaching step that waits for it."""
    k = checked.base_station
    if k is None:
        raise CellError("a base confirmation names no station")
    if not cycles.base.NEEDS_CONFIRMATION:
        raise CellError(f"base backend {cycles.cfg.base.backend!r} parks by itself; nothing to confirm")
    cycles.base.confirm(k)
    return f"base confirmed parked at station {k}"
