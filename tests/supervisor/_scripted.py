"""A StepRun whose worker calls are answered by a script (unit tests of steps, no Zenoh)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from cellctl.config import CellConfig
from cellctl.messages import StartParams, WireMessage
from cellctl.recording.index import CycleIndex
from cellctl.supervisor.context import CycleContext, StepRun
from cellctl.supervisor.recorder import NullRecorder, Recorder

Answer = Callable[[WireMessage], tuple[WireMessage, bytes | None]] | tuple[WireMessage, bytes | None]


class ScriptedRun(StepRun):
    """Answers ``call(role, op, ...)`` from ``script[(role, op)]`` (a reply or a function of the request).

    A function may raise a CellError to play a refusing worker; every call is kept in ``calls``.
    """

    def __init__(self, ctx: CycleContext, script: dict[tuple[str, str], Answer], name: str = "step") -> None:
        super().__init__(ctx, 1, name)
        self.script = script
        self.calls: list[tuple[str, str, WireMessage]] = []
        self.events: list[tuple[str, str]] = []
        ctx.post_event = lambda level, text: self.events.append((level, text))

    def call(self, role: str, op: str, msg: WireMessage, expect: type, **kw: Any) -> tuple[Any, bytes | None]:  # type: ignore[override]
        self.checkpoint()
        self.calls.append((role, op, msg))
        answer = self.script[(role, op)]
        reply = answer(msg) if callable(answer) else answer
        self.checkpoint()
        return reply


class ListRecorder(Recorder):
    """Keeps what a step records, in memory."""

    path = None
    rel = None

    def __init__(self) -> None:
        self.records: list[tuple[str, str]] = []

    def write_json(self, topic: str, schema: str, obj: dict[str, Any] | bytes) -> None:
        self.records.append((topic, schema))

    def write_message(self, topic: str, msg: WireMessage) -> None:
        self.records.append((topic, msg.type))

    def event(self, level: int, text: str) -> None:
        self.records.append(("/events", text))

    def image(self, topic: str, data: bytes, fmt: str, frame_id: str = "camera") -> None:
        self.records.append((topic, "foxglove.CompressedImage"))

    def close(self, result: Any) -> None:
        self.records.append(("close", result.outcome.value))


def context(
    cfg: CellConfig, *, params: StartParams | None = None, log: Recorder | None = None, **fields: Any
) -> CycleContext:
    p = params or StartParams()
    return CycleContext(
        cycle_id="c-1", cfg=cfg, session=None, log=log or NullRecorder(), mode=p.mode, params=p, **fields
    )


def index(tmp_path: Path) -> CycleIndex:
    return CycleIndex(tmp_path / "cells.db")
