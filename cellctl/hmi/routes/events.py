"""Events and alarms: ``/api/events``, ``/api/alarms`` (and acknowledging one), the ``/api/stream``
of server-sent events the pages follow."""

from __future__ import annotations

import asyncio
import json
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from fastapi import Path as FastApiPath
from fastapi.responses import StreamingResponse

from cellctl.hmi.routes.common import HttpError, NonceRequest, need_user

__all__ = ["events_router"]


def events_router(hmi: Any) -> APIRouter:
    """The event routes of ``hmi`` (:class:`~cellctl.hmi.server.Hmi`)."""
    hc = hmi.hcfg
    router = APIRouter(tags=["events"])

    @router.get("/api/events")
    async def events(limit: int = Query(default=200, ge=1, le=1_000_000)) -> dict[str, Any]:
        return {"events": hmi.link.events(max(1, min(limit, hc.events_kept)))}

    @router.get("/api/alarms")
    async def alarms() -> dict[str, Any]:
        return {"alarms": hmi.link.alarms()}

    @router.post("/api/alarms/{alarm_id}/ack")
    async def ack_alarm(
        alarm_id: Annotated[int, FastApiPath(ge=0, le=2**63 - 1)], request: Request, body: NonceRequest
    ) -> dict[str, Any]:
        s = need_user(hmi, request, body.nonce)
        a = hmi.link.ack_alarm(alarm_id, s.user)
        if a is None:
            raise HttpError(404, f"alarm {alarm_id} does not exist (or has aged out)")
        hmi.journal(kind="alarm_ack", user=s.user, alarm=alarm_id, text=a.text)
        return {"alarm": a.as_dict()}

    @router.get("/api/stream")
    async def stream(request: Request) -> StreamingResponse:
        """Server-sent events: one ``update`` with status, live view, events and alarms per change."""

        async def gen():
            hmi.streams += 1
            try:
                async for chunk in updates():
                    yield chunk
            finally:
                hmi.streams -= 1

        async def updates():
            last: tuple[int, int] | None = None
            quiet = 0.0
            while not await request.is_disconnected():
                v = (hmi.link.version, hmi.watcher.version)
                if v != last:
                    last, quiet = v, 0.0
                    data = {
                        **hmi.link.snapshot(),
                        "live": hmi.watcher.view(),
                        "events": hmi.link.events(50),
                        "alarms": hmi.link.alarms()[:50],
                    }
                    yield f"event: update\ndata: {json.dumps(data, separators=(',', ':'))}\n\n"
                elif quiet > 1.0:
                    # the reachability verdict changes with time alone (a silent daemon)
                    quiet = 0.0
                    yield f"event: reach\ndata: {json.dumps(hmi.link.snapshot())}\n\n"
                await asyncio.sleep(0.25)
                quiet += 0.25

        return StreamingResponse(gen(), media_type="text/event-stream", headers={"Cache-Control": "no-store"})

    return router
