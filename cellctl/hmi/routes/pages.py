"""The operator's pages (static HTML from ``templates/``, one per entry of :data:`PAGES`) and the
static files they load (a fixed table of ``static/``: no path from a URL reaches the file system)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import Response

from cellctl.hmi.routes.common import HttpError

__all__ = ["PAGES", "pages_router"]

HERE = Path(__file__).resolve().parent.parent
PAGES = {"": "overview", "live": "live", "history": "history", "review": "review", "events": "events", "login": "login"}
"""URL path → page name (its template)."""
TITLES = {
    "overview": "Overview", "live": "Cycle live", "history": "History", "review": "Review", "events": "Events",
    "login": "Login",
}  # fmt: skip


def _page(name: str, title: str) -> str:
    base = (HERE / "templates" / "base.html").read_text()
    body = (HERE / "templates" / f"{name}.html").read_text()
    return base.replace("{{title}}", title).replace("{{page}}", name).replace("{{content}}", body)


def pages_router() -> APIRouter:
    """``/static/{name}`` and every page of :data:`PAGES` (not in the OpenAPI schema)."""
    router = APIRouter()
    pages = {name: _page(name, TITLES[name]) for name in PAGES.values()}
    static = {p.name: p for p in (HERE / "static").iterdir() if p.is_file()}
    types = {".js": "text/javascript", ".css": "text/css", ".svg": "image/svg+xml", ".png": "image/png"}

    @router.get("/static/{name}", include_in_schema=False)
    async def static_file(name: str) -> Response:
        p = static.get(name)  # a fixed table: no path from the URL ever reaches the file system
        if p is None:
            raise HttpError(404, f"no static file {name[:80]!r}")
        return Response(p.read_bytes(), media_type=types.get(p.suffix, "application/octet-stream"),
                        headers={"Cache-Control": "no-cache"})  # fmt: skip

    def page_route(html: str) -> Callable:
        async def page() -> Response:
            return Response(html, media_type="text/html; charset=utf-8", headers={"Cache-Control": "no-store"})

        return page

    for route, name in PAGES.items():
        router.add_api_route(f"/{route}", page_route(pages[name]), methods=["GET"], include_in_schema=False)
    return router
