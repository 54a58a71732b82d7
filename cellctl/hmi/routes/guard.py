"""The HMI app's guard: one JSON error shape for every failure, and the checks every request passes
before any route runs (Host name, header / query / body sizes, same origin for state changes) plus
the security headers of every answer (docs/hmi/README.md)."""

from __future__ import annotations

import logging
from collections.abc import Callable

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse, Response

from cellctl.errors import CellError
from cellctl.hmi.config import HmiConfig
from cellctl.hmi.records import NotFound
from cellctl.hmi.routes.common import HttpError

__all__ = ["add_error_handlers", "add_guard"]

log = logging.getLogger("cellctl.hmi.server")  # the server's log, as before the routers were split out


def add_error_handlers(app: FastAPI) -> None:
    """Every error as ``{"error": ...}`` with a matching HTTP code (never FastAPI's ``{"detail"}``)."""

    @app.exception_handler(HttpError)
    async def _http_error(request: Request, err: HttpError) -> JSONResponse:
        headers = {"Retry-After": str(int(err.extra.pop("retry_after")))} if "retry_after" in err.extra else None
        return JSONResponse({"error": err.message, **err.extra}, status_code=err.code, headers=headers)

    @app.exception_handler(NotFound)
    async def _not_found(request: Request, err: NotFound) -> JSONResponse:
        return JSONResponse({"error": str(err)}, status_code=404)

    from starlette.exceptions import HTTPException as StarletteHTTPException

    @app.exception_handler(StarletteHTTPException)
    async def _starlette(request: Request, err: StarletteHTTPException) -> JSONResponse:
        # one error shape: 404 (no route), 405 (wrong method) … are {"error"} too, never {"detail"}
        msg = f"no such page or API: {request.url.path[:200]!r}" if err.status_code == 404 else str(err.detail)
        return JSONResponse({"error": msg}, status_code=err.status_code, headers=getattr(err, "headers", None))

    @app.exception_handler(CellError)
    async def _cell_error(request: Request, err: CellError) -> JSONResponse:
        # e.g. an unreadable index: the message names server paths, which stay in the HMI's log
        log.warning("HMI %s %s: %s", request.method, request.url.path[:200], err)
        return JSONResponse({"error": f"the cell's records cannot be read ({type(err).__name__})"}, status_code=503)

    @app.exception_handler(Exception)
    async def _bug(request: Request, err: Exception) -> JSONResponse:
        return JSONResponse({"error": "internal error (see the HMI log)"}, status_code=500)

    from fastapi.exceptions import RequestValidationError

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, err: RequestValidationError) -> JSONResponse:
        msgs = []
        for e in err.errors():
            loc = ".".join(str(x) for x in e.get("loc", ()) if x != "body")
            msgs.append(f"{loc or 'body'}: {e.get('msg')}")
        # a malformed URL (query or path parameter) is the request's fault: 400; a body that fails its model: 422
        in_url = any(e.get("loc", ("",))[0] in ("query", "path") for e in err.errors())
        return JSONResponse({"error": "; ".join(msgs)[:1000]}, status_code=400 if in_url else 422)


def add_guard(app: FastAPI, hc: HmiConfig) -> None:
    """The middleware every request passes (see the module docstring)."""
    hosts = hc.host_names()

    @app.middleware("http")
    async def _guard(request: Request, call_next: Callable) -> Response:
        host = _host_name(request.headers.get("host", ""))
        if host not in hosts:  # DNS rebinding: evil.example resolving to this HMI passes the Origin check
            return JSONResponse({"error": f"Host {host[:100]!r} is not one of this HMI's names"}, status_code=400)
        # h11 bounds only a head that arrives in pieces; one that arrives whole is counted here
        head = sum(len(k) + len(v) for k, v in request.scope.get("headers", ()))
        if head > hc.max_header_bytes:
            return JSONResponse(
                {"error": f"request headers of {head} bytes; at most {hc.max_header_bytes} accepted"}, status_code=431
            )
        qs = request.scope.get("query_string", b"")
        if len(qs) > hc.max_query_bytes:
            return JSONResponse(
                {"error": f"query string of {len(qs)} bytes; at most {hc.max_query_bytes} accepted"}, status_code=414
            )
        if request.method not in ("GET", "HEAD"):
            size = request.headers.get("content-length")
            if size is None or not size.isdigit():
                return JSONResponse({"error": "a request body needs a Content-Length"}, status_code=411)
            if int(size) > hc.max_body_bytes:
                return JSONResponse(
                    {"error": f"request body of {size} bytes; at most {hc.max_body_bytes} accepted"}, status_code=413
                )
            bad = _cross_origin(request)
            if bad:
                return JSONResponse({"error": bad}, status_code=403)
        response: Response = await call_next(request)
        h = response.headers
        h["X-Content-Type-Options"] = "nosniff"
        h["Referrer-Policy"] = "no-referrer"
        h["X-Frame-Options"] = "DENY"
        h["Content-Security-Policy"] = (
            "default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; frame-ancestors 'none'"
        )
        if request.url.path.startswith("/api/") and "cache-control" not in h:
            h["Cache-Control"] = "no-store"
        return response


def _host_name(host: str) -> str:
    """The Host header's name, lower case, without port or IPv6 brackets."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1 : host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


def _cross_origin(request: Request) -> str | None:
    """Why a state-changing request comes from another site, or None if it is same-origin."""
    site = request.headers.get("sec-fetch-site")
    if site is not None and site not in ("same-origin", "none"):
        return f"cross-site request refused (Sec-Fetch-Site: {site})"
    origin = request.headers.get("origin")
    if origin is not None:
        host = request.headers.get("host", "")
        if origin not in (f"http://{host}", f"https://{host}"):
            return f"request from origin {origin[:100]!r} refused; only this HMI's own pages may send it"
    return None
