"""The cell's state and commands: ``/api/status``, ``/api/cmd``, ``/api/packml``, ``/api/live`` (and its
image and heat map)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, Response
from pydantic import ValidationError

from cellctl.errors import WorkerTimeout, WorkerUnavailable
from cellctl.hmi.routes.common import CommandRequest, HttpError, explain, need_user
from cellctl.messages import Command, now_iso

__all__ = ["cell_router"]


def cell_router(hmi: Any) -> APIRouter:
    """The cell routes of ``hmi`` (:class:`~cellctl.hmi.server.Hmi`)."""
    hc = hmi.hcfg
    router = APIRouter(tags=["cell"])

    @router.get("/api/status")
    async def status() -> JSONResponse:
        """The last Status of the cell with ``reachable``; 503 while the cell is unreachable."""
        snap = hmi.link.snapshot()
        return JSONResponse(snap, status_code=200 if snap["reachable"] else 503)

    @router.post("/api/cmd")
    def command(request: Request, body: CommandRequest) -> JSONResponse:
        """Send a Command as the logged-in user; returns the daemon's Ack (409 when it refused)."""
        s = need_user(hmi, request, body.nonce)
        if (body.unit_mode is not None or body.unit_mode_code is not None) and s.role != "maintenance":
            raise HttpError(403, f"changing the unit mode needs the maintenance role; {s.user!r} is {s.role!r}")
        fields = body.model_dump(exclude={"nonce"}, exclude_none=True)
        try:
            # stamped here, on the HMI's clock: the supervisor refuses a stale or replayed copy (replay_guard)
            cmd = Command(**fields, request_id=hmi.link.next_request_id(s.user), user=f"hmi:{s.user}", stamp=now_iso())
        except ValidationError as err:
            raise HttpError(422, explain(err)) from None
        what = cmd.name if (cmd.command or cmd.cntrl_cmd) else f"unit mode {cmd.unit_mode or cmd.unit_mode_code}"
        try:
            ack = hmi.link.send(cmd, hc.command_timeout_s)
        except WorkerUnavailable as err:
            hmi.journal(kind="command", user=s.user, request_id=cmd.request_id, command=what, error=str(err))
            raise HttpError(503, str(err), reachable=False) from None
        except WorkerTimeout as err:
            hmi.journal(kind="command", user=s.user, request_id=cmd.request_id, command=what, error=str(err))
            raise HttpError(504, str(err)) from None
        hmi.journal(kind="command", user=s.user, request_id=cmd.request_id, command=what, accepted=ack.accepted,
                    reason=ack.reason, state=ack.state)  # fmt: skip
        verdict = "accepted" if ack.accepted else f"refused: {ack.reason}"
        hmi.link.note("info" if ack.accepted else "warning", f"{what} by {s.user}: {verdict}", f"hmi:{s.user}")
        a = ack.model_dump(mode="json")
        if not ack.accepted:
            return JSONResponse({"error": ack.reason, "ack": a}, status_code=409)
        return JSONResponse({"ack": a})

    @router.get("/api/packml")
    async def packml() -> dict[str, Any]:
        """The PackML states and transitions (states/packml.yaml) the Overview draws."""
        return hmi.packml

    @router.get("/api/live")
    async def live() -> JSONResponse:
        """The current (or last) cycle as the live page shows it."""
        return JSONResponse({"live": hmi.watcher.view()})

    @router.get("/api/live/image")
    async def live_image() -> Response:
        img = hmi.watcher.image()
        if img is None:
            raise HttpError(404, "no image captured in this cycle yet")
        return Response(img[0], media_type=f"image/{img[1]}", headers={"Cache-Control": "no-store"})

    @router.get("/api/live/heatmap")
    def live_heatmap() -> Response:
        """The newest classified view's heat map over its image (PNG); rendered in the thread pool."""
        png = hmi.watcher.heat_image()
        if png is None:
            raise HttpError(404, "no heat map classified in this cycle yet")
        return Response(png, media_type="image/png", headers={"Cache-Control": "no-store"})

    return router
