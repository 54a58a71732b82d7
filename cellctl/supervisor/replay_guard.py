"""Refusing a command that was already acted on, or that is too old: replayed traffic moves nothing.

A recorded cycle log holds the commands that drove it (``cell/<id>/cmd``), with their
``request_id``; republished onto a live cell they would run the cycle again (issue 32: a replay
drove a live cell). ``cellctl replay`` no longer publishes on live keys, and this guard is the
supervisor's own line of defence against any replayed or duplicated command:

* **request_id window** — a command whose ``request_id`` the supervisor accepted in the last
  :data:`DEDUP_WINDOW_S` seconds (at most :data:`DEDUP_WINDOW_IDS` ids, oldest forgotten first)
  is refused. Clients must therefore give every command its own id; a client that restarts its
  counter within the window (``plc-1`` again) gets a refusal naming the id, never a second move.
* **freshness** — a command that carries a ``stamp`` more than :data:`MAX_COMMAND_AGE_S` away
  from the supervisor's clock (old, or from the future: a forged or badly skewed clock) is
  refused. A stamp is optional (a PLC without a clock sends none); cellctl's own clients stamp.

Pure bookkeeping: no bus, no machine; the dispatcher thread alone calls it.
"""

from __future__ import annotations

import datetime as _dt
import time
from collections import OrderedDict

from cellctl.messages import Command

__all__ = ["DEDUP_WINDOW_IDS", "DEDUP_WINDOW_S", "MAX_COMMAND_AGE_S", "ReplayGuard"]

DEDUP_WINDOW_S = 600.0
"""How long an acted-on ``request_id`` is remembered (s): longer than any cycle's command exchange."""
DEDUP_WINDOW_IDS = 4096
"""How many acted-on ids are remembered at most (memory bound; ~10 commands/s for the whole window)."""
MAX_COMMAND_AGE_S = 60.0
"""A stamped command further than this from the supervisor's clock (s) is refused: generous for NTP-synced
hosts, far below the age of any recorded log worth replaying."""


class ReplayGuard:
    """The ``request_id`` window and the freshness limit of one supervisor."""

    def __init__(
        self, window_s: float = DEDUP_WINDOW_S, max_ids: int = DEDUP_WINDOW_IDS, max_age_s: float = MAX_COMMAND_AGE_S
    ) -> None:
        self.window_s, self.max_ids, self.max_age_s = window_s, max_ids, max_age_s
        self._seen: OrderedDict[str, float] = OrderedDict()
        """request_id -> monotonic time it was acted on, oldest first."""

    def refusal(self, cmd: Command, now: float | None = None, wall: _dt.datetime | None = None) -> str | None:
        """Why ``cmd`` must not be acted on, or None.

        Args:
            now: monotonic time (s), for tests; default ``time.monotonic()``.
            wall: the supervisor's UTC clock, for tests; default now.
        """
        now = time.monotonic() if now is None else now
        self._forget(now)
        rid = cmd.request_id
        if rid is not None and rid in self._seen:
            ago = now - self._seen[rid]
            return (
                f"request_id {rid!r} was already acted on {ago:.1f} s ago (a replayed or repeated command); "
                f"every command needs its own request_id (ids are remembered {self.window_s:g} s)"
            )
        if cmd.stamp is not None:
            sent = _dt.datetime.fromisoformat(cmd.stamp)
            wall = wall or _dt.datetime.now(_dt.UTC)
            age = (wall - sent).total_seconds()
            if abs(age) > self.max_age_s:
                when = f"{age:.0f} s old" if age > 0 else f"{-age:.0f} s in the future"
                return (
                    f"stamp {cmd.stamp!r} is {when} (a replayed command or a skewed clock); "
                    f"commands are accepted within {self.max_age_s:g} s of the supervisor's clock"
                )
        return None

    def acted(self, cmd: Command, now: float | None = None) -> None:
        """Remember that ``cmd`` was acted on (accepted)."""
        if cmd.request_id is None:
            return
        self._seen[cmd.request_id] = time.monotonic() if now is None else now
        self._seen.move_to_end(cmd.request_id)
        while len(self._seen) > self.max_ids:
            self._seen.popitem(last=False)

    def _forget(self, now: float) -> None:
        while self._seen:
            rid, t = next(iter(self._seen.items()))
            if now - t <= self.window_s:
                return
            del self._seen[rid]
