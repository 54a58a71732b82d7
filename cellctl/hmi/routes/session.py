"""Sessions: log in, log out, who is logged in (``/api/login``, ``/api/logout``, ``/api/session``)."""

from __future__ import annotations

import asyncio
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from cellctl.hmi.auth import hash_password, verify_password
from cellctl.hmi.routes.common import COOKIE, HttpError, LoginRequest, need_user, session_of

__all__ = ["session_router"]

_DUMMY_HASH = hash_password("not-a-user-password", salt=b"\0" * 16)


def session_router(hmi: Any) -> APIRouter:
    """The session routes of ``hmi`` (:class:`~cellctl.hmi.server.Hmi`)."""
    hc = hmi.hcfg
    router = APIRouter(tags=["session"])

    @router.post("/api/login")
    async def login(request: Request, body: LoginRequest) -> JSONResponse:
        """Log in; sets the session cookie and returns the CSRF token."""
        client = request.client.host if request.client else "?"
        wait = hmi.throttle.retry_after(body.user, client)
        if wait > 0:
            raise HttpError(429, f"too many failed logins; try again in {wait:.0f} s", retry_after=max(1, wait))
        user = hc.user(body.user)
        # Check a dummy hash for unknown users too, so the answer time does not tell which names exist.
        ok = await asyncio.to_thread(verify_password, body.password, user.password_hash if user else _DUMMY_HASH)
        if user is None or not ok:
            hmi.throttle.failed(body.user, client)
            hmi.journal(kind="login_failed", user=body.user[:64], client=client)
            raise HttpError(401, "wrong user name or password")
        hmi.throttle.succeeded(body.user, client)
        s = hmi.sessions.create(user.name, user.role)
        hmi.journal(kind="login", user=user.name, role=user.role, client=client)
        hmi.link.note("info", f"{user.name} ({user.role}) logged in", f"hmi:{user.name}")
        resp = JSONResponse({"user": s.user, "role": s.role, "csrf": s.csrf})
        resp.set_cookie(
            COOKIE, s.token, httponly=True, samesite="strict", secure=hc.cookie_secure, path="/",
            max_age=int(hc.session_max_s),
        )  # fmt: skip
        return resp

    @router.post("/api/logout")
    async def logout(request: Request) -> JSONResponse:
        s = need_user(hmi, request, None)
        hmi.sessions.drop(s.token)
        hmi.journal(kind="logout", user=s.user)
        resp = JSONResponse({"user": None})
        resp.delete_cookie(COOKIE, path="/")
        return resp

    @router.get("/api/session")
    async def session(request: Request) -> JSONResponse:
        """Who is logged in (and the CSRF token for their POSTs), or ``user: null``."""
        s, why = session_of(hmi, request)
        if s is None:
            resp = JSONResponse({"user": None, "expired": why == "expired", "users_configured": bool(hc.users)})
            if why:
                resp.delete_cookie(COOKIE, path="/")
            return resp
        return JSONResponse({"user": s.user, "role": s.role, "csrf": s.csrf})

    return router
