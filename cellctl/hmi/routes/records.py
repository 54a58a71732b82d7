"""The cell's records (the MES's view): ``/api/cycles`` (filtered), one cycle's result, record, log,
dirt map, images and heat maps, and ``/api/audit``. Read-only, no login."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi import Path as FastApiPath
from fastapi.responses import FileResponse, JSONResponse, Response

from cellctl.errors import CellError
from cellctl.hmi.records import CycleFilter
from cellctl.hmi.routes.common import HttpError

__all__ = ["records_router"]


def records_router(hmi: Any) -> APIRouter:
    """The record routes of ``hmi`` (:class:`~cellctl.hmi.server.Hmi`)."""
    router = APIRouter(tags=["records"])

    @router.get("/api/cycles")
    def cycles(
        outcome: str | None = None,
        verdict: str | None = None,
        bin: str | None = None,  # the MES's name for the filter
        since: str | None = None,
        until: str | None = None,
        limit: int = 50,
        before: int | None = Query(default=None, ge=1, le=2**63 - 1),  # SQLite's integer range
    ) -> dict[str, Any]:
        """Cycles of the index, newest first; filter by outcome, verdict, bin type, start date."""
        if not 1 <= limit <= 500:
            raise HttpError(422, f"limit={limit} is out of range; expected 1..500")
        try:
            rows = hmi.records.cycles(CycleFilter(outcome, verdict, bin, since, until, limit, before))
        except ValueError as err:
            raise HttpError(422, str(err)) from None
        return {"cycles": rows}

    @router.get("/api/cycles/{cycle_id}")
    def cycle_result(cycle_id: str) -> JSONResponse:
        """The cycle's CycleResult as recorded in its log."""
        d = hmi.records.detail(cycle_id)
        if d["result"] is None:
            state = d["row"]["outcome"] or "running"
            raise HttpError(409, f"cycle {cycle_id!r} has no CycleResult in its log (outcome: {state})")
        return JSONResponse(d["result"])

    @router.get("/api/cycles/{cycle_id}/record")
    def cycle_record(cycle_id: str) -> dict[str, Any]:
        """Index row, CycleResult, per-view images with scores and the record's audit status."""
        d = hmi.records.detail(cycle_id)
        try:
            audit = hmi.records.audit_status(cycle_id)
        except CellError as err:
            audit = {"status": "unknown", "error": str(err)}
        try:
            release = hmi.review.release_state(cycle_id)
        except CellError as err:  # e.g. an unreadable review ledger: the record itself still shows
            release = {"state": "unknown", "error": str(err)}
        return {**d, "audit": audit, "release": release}

    @router.get("/api/cycles/{cycle_id}/log")
    def cycle_log(cycle_id: str) -> FileResponse:
        """The cycle's MCAP (only files inside the logs folder are ever served)."""
        p = hmi.records.log_file(cycle_id)
        return FileResponse(p, media_type="application/octet-stream", filename=f"{cycle_id}.mcap")

    @router.get("/api/cycles/{cycle_id}/dirt_map.png")
    def dirt_map(cycle_id: str) -> Response:
        return Response(hmi.records.dirt_map_png(cycle_id), media_type="image/png")

    @router.get("/api/cycles/{cycle_id}/images/{n}")
    def cycle_image(cycle_id: str, n: Annotated[int, FastApiPath(ge=0, le=1_000_000)]) -> Response:
        data, fmt = hmi.records.image(cycle_id, n)
        return Response(data, media_type=f"image/{fmt}", headers={"Cache-Control": "max-age=3600"})

    @router.get("/api/cycles/{cycle_id}/heatmaps/{n}")
    def cycle_heatmap(cycle_id: str, n: Annotated[int, FastApiPath(ge=0, le=1_000_000)]) -> Response:
        """The heat map of the view whose image is ``/images/{n}``, over that image (PNG)."""
        png = hmi.records.heat_image(cycle_id, n)
        return Response(png, media_type="image/png", headers={"Cache-Control": "max-age=3600"})

    @router.get("/api/audit")
    def audit() -> dict[str, Any]:
        """``cellctl audit verify`` of the index and logs: ok, head (seq, row_hash), findings."""
        try:
            return hmi.records.audit()
        except CellError as err:
            raise HttpError(503, str(err)) from None

    return router
