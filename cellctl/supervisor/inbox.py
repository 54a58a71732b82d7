"""What the supervisor listens to on the bus, turned into dispatcher events by callbacks that never block."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import zenoh

from cellctl.bus import keys
from cellctl.supervisor.events import AliveChanged, CommandReceived, DispatchEvent, EventReceived, StatusQuery

__all__ = ["declare_inbox", "undeclare_all"]


def declare_inbox(session: Any, cell_id: str, put: Callable[[DispatchEvent], None]) -> list[Any]:
    """Commands (put and query), status queries, worker liveliness, workers' fault events, and the
    supervisor's own token.

    The subscriber and queryables take Zenoh's default callback channel: each callback only
    enqueues, so the dispatcher's unbounded queue, not Zenoh, holds a burst.
    """
    s, c = session, cell_id
    return [
        s.declare_subscriber(keys.cmd(c), lambda sample: put(CommandReceived(sample.payload.to_bytes()))),
        s.declare_queryable(keys.cmd(c), lambda q: put(CommandReceived(q.payload.to_bytes() if q.payload else b"", q))),
        s.declare_queryable(keys.status(c), lambda q: put(StatusQuery(q))),
        s.liveliness().declare_subscriber(
            keys.alive_all(c),
            lambda sample: put(AliveChanged(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)),
            history=True,
        ),
        # a worker's fault report (``robot fault: protective stop``) gives a lost token its reason
        *(
            s.declare_subscriber(
                keys.worker_fault(c, role), lambda sample: put(EventReceived(sample.payload.to_bytes()))
            )
            for role in keys.ROLES
        ),
        s.liveliness().declare_token(keys.alive(c, "supervisor")),
    ]


def undeclare_all(decls: list[Any]) -> None:
    """Undeclare in reverse order; what the closing session already undeclared is skipped."""
    for d in reversed(decls):
        try:
            d.undeclare()
        except Exception:  # already closed with the session
            pass
    decls.clear()
