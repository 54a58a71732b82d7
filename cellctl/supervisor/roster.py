"""Which workers are alive: liveliness events counted per role, corrected from the router.

Zenoh liveliness events can arrive out of order around a reconnect (a frozen worker's late
DELETE after its new PUT for the same key), so the counts are re-read from the router every
:data:`RECONCILE_S` and whenever a decision depends on them (:meth:`WorkerRoster.missing`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable

import zenoh

from cellctl.bus import keys
from cellctl.errors import WorkerUnavailable
from cellctl.supervisor.events import AliveSync

__all__ = ["ACTIVE_STATES", "RECONCILE_S", "WorkerRoster", "liveliness_query"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

RECONCILE_S = 2.0
"""How often worker liveliness is re-read from the router (bounds a wrong count's lifetime)."""

ACTIVE_STATES = ("Starting", "Execute", "Unholding", "Unsuspending", "Completing")
"""PackML states in which losing a required worker ends (or holds) the cycle; elsewhere it is a warning."""

AliveQuery = Callable[[], dict[str, int]]


def liveliness_query(session: zenoh.Session | None, cell_id: str) -> AliveQuery:
    """Live tokens per role, asked from the router (blocks up to 1 s: never on the dispatcher).

    Without a session the query raises, and :meth:`WorkerRoster.missing` falls back to the event counts.
    """

    def query() -> dict[str, int]:
        if session is None:
            raise WorkerUnavailable("no bus session to ask the router for worker liveliness")
        counts: dict[str, int] = {}
        for r in session.liveliness().get(keys.alive_all(cell_id), timeout=1.0):
            if r.ok is not None:
                role = keys.role_from_alive_key(cell_id, str(r.ok.key_expr))
                if role is not None and role != "supervisor":
                    counts[role] = counts.get(role, 0) + 1
        return counts

    return query


class WorkerRoster:
    """Live tokens per worker role.

    Args:
        cell_id: the cell whose ``cell/<id>/alive/<role>`` keys are counted.
        required: roles a cycle cannot run without.
        query: asks the router for the live tokens now (see :func:`liveliness_query`).
    """

    def __init__(self, cell_id: str, required: Iterable[str], query: AliveQuery) -> None:
        self.cell_id = cell_id
        self.required = tuple(required)
        self._query = query
        self._alive: dict[str, int] = {}

    def count(self, role: str) -> int:
        return self._alive.get(role, 0)

    def workers(self) -> dict[str, bool]:
        """Role → alive, for every known role (the Status field)."""
        return {r: self.count(r) > 0 for r in keys.ROLES}

    def changed(self, key: str, present: bool) -> str | None:
        """Count one liveliness event (dispatcher); return the role it concerns, None for others."""
        role = keys.role_from_alive_key(self.cell_id, key)
        if role is None or role == "supervisor":
            return None
        self._alive[role] = max(0, self.count(role) + (1 if present else -1))
        return role

    def lost(self, role: str) -> bool:
        """True when ``role`` is required and has no live token left."""
        return self.count(role) == 0 and role in self.required

    def sync(self, counts: dict[str, int]) -> bool:
        """Take the router's counts as the truth (dispatcher); True if that changed anything.

        Never an abort from here: losing a worker mid-cycle is the DELETE event's job.
        """
        fresh = {r: counts.get(r, 0) for r in keys.ROLES}
        if all(fresh[r] == self.count(r) for r in keys.ROLES):
            return False
        log.info("worker liveliness corrected from the router: %s (events said %s)", fresh, self._alive)
        self._alive.update(fresh)
        return True

    def query(self) -> dict[str, int]:
        """Ask the router now (activation/reconcile threads only: it blocks)."""
        return self._query()

    def reconcile(self, period_s: float, stop: threading.Event, put: Callable[[AliveSync], None]) -> None:
        """Every ``period_s``, put the router's counts as an :class:`AliveSync` (own thread) until ``stop``."""
        while not stop.wait(period_s):
            try:
                put(AliveSync(self._query()))
            except Exception:  # the session is closing
                return

    def missing(self, on_counts: Callable[[dict[str, int]], None] | None = None) -> list[str]:
        """Required roles with no live token, asked now rather than taken from the event count.

        ``on_counts`` receives the router's answer (to correct the counts on the dispatcher).
        """
        try:
            alive = self._query()
        except Exception:  # a closing session (or none): fall back to what the events said
            alive = dict(self._alive)
        else:
            if on_counts is not None:
                on_counts(alive)
        return [r for r in self.required if alive.get(r, 0) == 0]
