"""What the dispatcher reacts to: one typed event per kind, put on its queue by Zenoh callbacks,
activation threads and timers (never handled there), matched in :meth:`Supervisor._dispatch`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

__all__ = [
    "AliveChanged",
    "AliveSync",
    "CommandReceived",
    "DispatchEvent",
    "EventReceived",
    "Fire",
    "PublishStatus",
    "Query",
    "Shutdown",
    "StatusQuery",
    "StepDone",
]


class Query(Protocol):
    """The part of a ``zenoh.Query`` the dispatcher uses (a fake in unit tests)."""

    @property
    def key_expr(self) -> object: ...

    def reply(self, key_expr: object, payload: bytes, *, congestion_control: object = None) -> None: ...

    def drop(self) -> None: ...


@dataclass(frozen=True)
class CommandReceived:
    """A payload on ``cell/<id>/cmd``; ``query`` is None for a put (answered on ``cmd/ack``)."""

    payload: bytes
    query: Query | None = None


@dataclass(frozen=True)
class StepDone:
    """An activation finished: its token, its outcome (``failed`` with a reason on a CellError)."""

    token: int
    outcome: str | None
    reason: str | None = None


@dataclass(frozen=True)
class AliveChanged:
    """A liveliness token appeared (``present``) or vanished."""

    key: str
    present: bool


@dataclass(frozen=True)
class EventReceived:
    """An Event on ``cell/<id>/<role>/fault``: a worker's fault report (``<role> fault: …``)."""

    payload: bytes


@dataclass(frozen=True)
class AliveSync:
    """Live tokens per role as the router answered a liveliness query (the truth)."""

    counts: dict[str, int]


@dataclass(frozen=True)
class StatusQuery:
    """A get on ``cell/<id>/status``."""

    query: Query


@dataclass(frozen=True)
class PublishStatus:
    """Publish (and record) the status now."""


@dataclass(frozen=True)
class Fire:
    """Fire a machine trigger from the dispatcher thread (e.g. the auto-reset after Complete)."""

    trigger: str


@dataclass(frozen=True)
class Shutdown:
    """Close the open cycle and end the dispatcher."""


DispatchEvent = (
    CommandReceived
    | StepDone
    | AliveChanged
    | EventReceived
    | AliveSync
    | StatusQuery
    | PublishStatus
    | Fire
    | Shutdown
)
