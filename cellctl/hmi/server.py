"""The HMI web server: pages, the REST API and server-sent events, on FastAPI + uvicorn.

Layout of the process (``cellctl hmi``)::

    CellLink     Zenoh client: Status, events → alarms, results; commands by query → Ack
    LiveWatcher  tails the running cycle's MCAP (images, per-view verdicts, k/N) at 4 Hz
    CycleRecords read-only index, logs, dirt maps, audit
    FastAPI app  pages (static HTML + one JS file), /api/*, /api/stream (SSE), /openapi.json

Security (docs/hmi/README.md): reading needs no login; commands and alarm acknowledgement need
a session of a configured user (cookie ``HttpOnly``, ``SameSite=Strict``), the session's CSRF
token in ``X-CSRF-Token`` and a fresh ``nonce`` per request (a replay is refused). Every POST
from another origin is refused, long query strings and large bodies are refused before any
work, and errors are JSON ``{"error": "..."}`` with a matching HTTP code.
"""

from __future__ import annotations

import asyncio
import hmac
import json
import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import FastAPI, Query, Request
from fastapi import Path as FastApiPath
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from pydantic import BaseModel, ConfigDict, Field, StrictInt, StrictStr, ValidationError

from cellctl.config import CellConfig
from cellctl.errors import CellError, WorkerTimeout, WorkerUnavailable
from cellctl.hmi.auth import SessionStore, hash_password, verify_password
from cellctl.hmi.config import HmiConfig
from cellctl.hmi.link import CellLink
from cellctl.hmi.live import LiveCycle, McapTail
from cellctl.hmi.records import CycleFilter, CycleRecords, NotFound
from cellctl.hmi.review import Review
from cellctl.login_throttle import LoginThrottle
from cellctl.messages import Command, now_iso

__all__ = ["Hmi", "HmiServer", "LiveWatcher", "build_app"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

HERE = Path(__file__).resolve().parent
COOKIE = "cellctl_hmi"
PAGES = {"": "overview", "live": "live", "history": "history", "review": "review", "events": "events", "login": "login"}
_DUMMY_HASH = hash_password("not-a-user-password", salt=b"\0" * 16)


class HttpError(Exception):
    def __init__(self, code: int, message: str, **extra: Any) -> None:
        self.code, self.message, self.extra = code, message, extra
        super().__init__(message)


# --- request bodies (also the OpenAPI schema) ---------------------------------------------------


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid")


class LoginRequest(_Body):
    user: StrictStr = Field(max_length=64)
    password: StrictStr = Field(max_length=256)


class CommandRequest(_Body):
    """A cellctl/Command without ``request_id``/``user`` (the HMI sets both from the login)."""

    type: Literal["cellctl/Command"] = "cellctl/Command"
    v: Literal[1] = 1
    # strict: "1" or true is not a command code (JSON has integers; a client sending strings is confused)
    command: StrictStr | None = None
    cntrl_cmd: StrictInt | None = None
    unit_mode: StrictStr | None = None
    unit_mode_code: StrictInt | None = None
    params: dict[str, Any] = Field(default_factory=dict)
    nonce: str = Field(min_length=16, max_length=64, pattern=r"^[A-Za-z0-9_-]+$", description="fresh per request")


class NonceRequest(_Body):
    nonce: str = Field(min_length=16, max_length=64, pattern=r"^[A-Za-z0-9_-]+$")


# --- the live cycle -------------------------------------------------------------------------------


class LiveWatcher:
    """Follows the cell's current (or last) cycle log; ``version`` changes when the view does.

    Args:
        on_message: also called with each new log message (the live Foxglove view).
    """

    def __init__(
        self, link: CellLink, records: CycleRecords, period_s: float = 0.25, on_message: Callable | None = None
    ) -> None:
        self.link, self.records, self.period_s = link, records, period_s
        self.on_message = on_message
        self.version = 0
        self._lock = threading.Lock()
        self.live: LiveCycle | None = None
        self._tail: McapTail | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="hmi-live", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.step()
            except Exception:  # a damaged log or index must not end the live view
                log.exception("live view update failed")
            self._stop.wait(self.period_s)

    def step(self) -> None:
        st = self.link.snapshot()["status"]
        want = st.get("cycle_id") if st else None
        if want is None and self.live is None:
            row = self.records.running_row()
            want = row.cycle_id if row is not None else None
        if want is not None and (self.live is None or self.live.cycle_id != want):
            try:
                path = self.records.log_file(want)
            except (NotFound, CellError):
                return  # the index row may lag the Status by a moment
            live = LiveCycle(self.link.cell, want, max_pixels=self.records.cfg.camera.max_image_pixels)
            sink = self.on_message

            def fold(m: Any, live: LiveCycle = live) -> None:
                live.fold(m)
                if sink is not None:
                    sink(m)

            with self._lock:
                self.live, self._tail = live, McapTail(path, fold)
                self.version += 1
        if self._tail is not None and self._tail.poll():
            with self._lock:
                self.version += 1

    def view(self) -> dict[str, Any] | None:
        with self._lock:
            return self.live.as_dict() if self.live is not None else None

    def image(self) -> tuple[bytes, str] | None:
        with self._lock:
            return self.live.image() if self.live is not None else None

    def heat_image(self) -> bytes | None:
        with self._lock:
            return self.live.heat_image() if self.live is not None else None

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


# --- the process ----------------------------------------------------------------------------------


class Hmi:
    """Everything one HMI process holds; :func:`build_app` serves it.

    Args:
        clock: monotonic seconds for sessions and the login throttle (injected in tests).
    """

    def __init__(self, cfg: CellConfig, hcfg: HmiConfig, clock: Callable[[], float] = time.monotonic) -> None:
        self.cfg, self.hcfg = cfg, hcfg
        self.link = CellLink(cfg, hcfg.stale_s, hcfg.events_kept, reopen_s=max(3 * hcfg.stale_s, 2.0))
        self.records = CycleRecords(cfg)
        self.review = Review(cfg, self.records)
        self.foxglove: Any = None
        if hcfg.foxglove.enabled:
            from cellctl.hmi.foxglove_live import FoxgloveLive

            self.foxglove = FoxgloveLive(cfg, hcfg.foxglove, self.link)
        self.watcher = LiveWatcher(self.link, self.records, on_message=self.foxglove.forward if self.foxglove else None)
        self.sessions = SessionStore(hcfg.session_idle_s, hcfg.session_max_s, clock)
        self.throttle = LoginThrottle(hcfg.login, "HMI", clock)
        self.journal_path = cfg.path(cfg.recording.dir) / "hmi-journal.jsonl"
        self._journal_lock = threading.Lock()
        self.packml = _packml_graph()
        self.streams = 0
        """Event streams open now (pages connected)."""

    def journal(self, **entry: Any) -> None:
        """Append one line to the HMI's own journal (who did what, when); never raises."""
        line = json.dumps({"stamp": now_iso(), **entry}, separators=(",", ":"))
        try:
            with self._journal_lock:
                self.journal_path.parent.mkdir(parents=True, exist_ok=True)
                with self.journal_path.open("a") as f:
                    f.write(line + "\n")
        except OSError as err:
            log.warning("HMI journal %s not written: %s", self.journal_path, err)

    def close(self) -> None:
        self.watcher.close()
        if self.foxglove is not None:
            self.foxglove.close()
        self.link.close()
        self.records.close()


def _packml_graph() -> dict[str, Any]:
    """States (name, code, acting) and transitions of ``states/packml.yaml`` for the diagram."""
    from cellctl.config import project_root, safe_yaml_load
    from cellctl.supervisor.definition import load_packml

    path = project_root() / "states" / "packml.yaml"
    raw = safe_yaml_load(path.read_text(), str(path))
    d = load_packml(path, behaviours=[s["behaviour"] for s in raw["states"] if s.get("behaviour")])
    edges = [{"from": s, "to": t, "label": c} for c, table in d.commands.items() for s, t in table.items()]
    edges += [{"from": s, "to": t, "label": "SC"} for s, t in d.state_complete.items()]
    return {"states": [{"name": s.name, "code": s.code, "acting": s.acting} for s in d.states.values()], "edges": edges}


# --- the app ----------------------------------------------------------------------------------------


def _page(name: str, title: str) -> str:
    base = (HERE / "templates" / "base.html").read_text()
    body = (HERE / "templates" / f"{name}.html").read_text()
    return base.replace("{{title}}", title).replace("{{page}}", name).replace("{{content}}", body)


def build_app(hmi: Hmi) -> FastAPI:  # one place that lists every route reads best
    """The FastAPI application of ``hmi`` (routes, security checks, error mapping)."""
    hc = hmi.hcfg
    app = FastAPI(
        title="cellctl HMI",
        version="1",
        description="Operator screen and REST API of a cellctl inspection cell (read-only without login).",
        docs_url=None,  # the Swagger page loads its assets from a CDN; the schema is at /openapi.json
        redoc_url=None,
    )
    titles = {
        "overview": "Overview", "live": "Cycle live", "history": "History", "review": "Review", "events": "Events",
        "login": "Login",
    }  # fmt: skip
    pages = {name: _page(name, titles[name]) for name in PAGES.values()}

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

    # --- sessions ------------------------------------------------------------------------------

    def session_of(request: Request) -> tuple[Any, str | None]:
        return hmi.sessions.get(request.cookies.get(COOKIE))

    def need_user(request: Request, nonce: str | None, roles: tuple[str, ...] = ("operator", "maintenance")) -> Any:
        s, why = session_of(request)
        if s is None:
            if why == "expired":
                raise HttpError(401, "your session has expired; log in again", login=True)
            raise HttpError(401, "log in first: commands need an operator or maintenance login", login=True)
        token = request.headers.get("x-csrf-token", "")
        if not token or not hmac.compare_digest(token.encode("utf-8", "replace"), s.csrf.encode()):
            raise HttpError(403, "missing or wrong CSRF token (X-CSRF-Token); reload the page")
        if s.role not in roles:
            raise HttpError(403, f"user {s.user!r} has role {s.role!r}; this needs one of {list(roles)}")
        if nonce is not None and not s.use_nonce(nonce):
            raise HttpError(409, f"request nonce {nonce!r} was used before: a replayed request is refused")
        return s

    from cellctl.hmi.review_api import add_review_routes

    add_review_routes(app, hmi, need_user, HttpError)

    @app.post("/api/login", tags=["session"])
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

    @app.post("/api/logout", tags=["session"])
    async def logout(request: Request) -> JSONResponse:
        s = need_user(request, None)
        hmi.sessions.drop(s.token)
        hmi.journal(kind="logout", user=s.user)
        resp = JSONResponse({"user": None})
        resp.delete_cookie(COOKIE, path="/")
        return resp

    @app.get("/api/session", tags=["session"])
    async def session(request: Request) -> JSONResponse:
        """Who is logged in (and the CSRF token for their POSTs), or ``user: null``."""
        s, why = session_of(request)
        if s is None:
            resp = JSONResponse({"user": None, "expired": why == "expired", "users_configured": bool(hc.users)})
            if why:
                resp.delete_cookie(COOKIE, path="/")
            return resp
        return JSONResponse({"user": s.user, "role": s.role, "csrf": s.csrf})

    # --- cell state and commands -----------------------------------------------------------------

    @app.get("/api/status", tags=["cell"])
    async def status() -> JSONResponse:
        """The last Status of the cell with ``reachable``; 503 while the cell is unreachable."""
        snap = hmi.link.snapshot()
        return JSONResponse(snap, status_code=200 if snap["reachable"] else 503)

    @app.post("/api/cmd", tags=["cell"])
    def command(request: Request, body: CommandRequest) -> JSONResponse:
        """Send a Command as the logged-in user; returns the daemon's Ack (409 when it refused)."""
        s = need_user(request, body.nonce)
        if (body.unit_mode is not None or body.unit_mode_code is not None) and s.role != "maintenance":
            raise HttpError(403, f"changing the unit mode needs the maintenance role; {s.user!r} is {s.role!r}")
        fields = body.model_dump(exclude={"nonce"}, exclude_none=True)
        try:
            # stamped here, on the HMI's clock: the supervisor refuses a stale or replayed copy (replay_guard)
            cmd = Command(**fields, request_id=hmi.link.next_request_id(s.user), user=f"hmi:{s.user}", stamp=now_iso())
        except ValidationError as err:
            raise HttpError(422, _explain(err)) from None
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

    @app.get("/api/packml", tags=["cell"])
    async def packml() -> dict[str, Any]:
        """The PackML states and transitions (states/packml.yaml) the Overview draws."""
        return hmi.packml

    @app.get("/api/live", tags=["cell"])
    async def live() -> JSONResponse:
        """The current (or last) cycle as the live page shows it."""
        return JSONResponse({"live": hmi.watcher.view()})

    @app.get("/api/live/image", tags=["cell"])
    async def live_image() -> Response:
        img = hmi.watcher.image()
        if img is None:
            raise HttpError(404, "no image captured in this cycle yet")
        return Response(img[0], media_type=f"image/{img[1]}", headers={"Cache-Control": "no-store"})

    @app.get("/api/live/heatmap", tags=["cell"])
    def live_heatmap() -> Response:
        """The newest classified view's heat map over its image (PNG); rendered in the thread pool."""
        png = hmi.watcher.heat_image()
        if png is None:
            raise HttpError(404, "no heat map classified in this cycle yet")
        return Response(png, media_type="image/png", headers={"Cache-Control": "no-store"})

    @app.get("/api/events", tags=["events"])
    async def events(limit: int = Query(default=200, ge=1, le=1_000_000)) -> dict[str, Any]:
        return {"events": hmi.link.events(max(1, min(limit, hc.events_kept)))}

    @app.get("/api/alarms", tags=["events"])
    async def alarms() -> dict[str, Any]:
        return {"alarms": hmi.link.alarms()}

    @app.post("/api/alarms/{alarm_id}/ack", tags=["events"])
    async def ack_alarm(
        alarm_id: Annotated[int, FastApiPath(ge=0, le=2**63 - 1)], request: Request, body: NonceRequest
    ) -> dict[str, Any]:
        s = need_user(request, body.nonce)
        a = hmi.link.ack_alarm(alarm_id, s.user)
        if a is None:
            raise HttpError(404, f"alarm {alarm_id} does not exist (or has aged out)")
        hmi.journal(kind="alarm_ack", user=s.user, alarm=alarm_id, text=a.text)
        return {"alarm": a.as_dict()}

    @app.get("/api/stream", tags=["events"])
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

    # --- records (MES) ---------------------------------------------------------------------------

    @app.get("/api/cycles", tags=["records"])
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

    @app.get("/api/cycles/{cycle_id}", tags=["records"])
    def cycle_result(cycle_id: str) -> JSONResponse:
        """The cycle's CycleResult as recorded in its log."""
        d = hmi.records.detail(cycle_id)
        if d["result"] is None:
            state = d["row"]["outcome"] or "running"
            raise HttpError(409, f"cycle {cycle_id!r} has no CycleResult in its log (outcome: {state})")
        return JSONResponse(d["result"])

    @app.get("/api/cycles/{cycle_id}/record", tags=["records"])
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

    @app.get("/api/cycles/{cycle_id}/log", tags=["records"])
    def cycle_log(cycle_id: str) -> FileResponse:
        """The cycle's MCAP (only files inside the logs folder are ever served)."""
        p = hmi.records.log_file(cycle_id)
        return FileResponse(p, media_type="application/octet-stream", filename=f"{cycle_id}.mcap")

    @app.get("/api/cycles/{cycle_id}/dirt_map.png", tags=["records"])
    def dirt_map(cycle_id: str) -> Response:
        return Response(hmi.records.dirt_map_png(cycle_id), media_type="image/png")

    @app.get("/api/cycles/{cycle_id}/images/{n}", tags=["records"])
    def cycle_image(cycle_id: str, n: Annotated[int, FastApiPath(ge=0, le=1_000_000)]) -> Response:
        data, fmt = hmi.records.image(cycle_id, n)
        return Response(data, media_type=f"image/{fmt}", headers={"Cache-Control": "max-age=3600"})

    @app.get("/api/cycles/{cycle_id}/heatmaps/{n}", tags=["records"])
    def cycle_heatmap(cycle_id: str, n: Annotated[int, FastApiPath(ge=0, le=1_000_000)]) -> Response:
        """The heat map of the view whose image is ``/images/{n}``, over that image (PNG)."""
        png = hmi.records.heat_image(cycle_id, n)
        return Response(png, media_type="image/png", headers={"Cache-Control": "max-age=3600"})

    @app.get("/api/audit", tags=["records"])
    def audit() -> dict[str, Any]:
        """``cellctl audit verify`` of the index and logs: ok, head (seq, row_hash), findings."""
        try:
            return hmi.records.audit()
        except CellError as err:
            raise HttpError(503, str(err)) from None

    # --- pages and static files ------------------------------------------------------------------

    static = {p.name: p for p in (HERE / "static").iterdir() if p.is_file()}
    types = {".js": "text/javascript", ".css": "text/css", ".svg": "image/svg+xml", ".png": "image/png"}

    @app.get("/static/{name}", include_in_schema=False)
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
        app.add_api_route(f"/{route}", page_route(pages[name]), methods=["GET"], include_in_schema=False)

    return app


def _explain(err: ValidationError) -> str:
    """One clause per problem: the field, what is wrong, the value sent."""
    out = []
    for e in err.errors():
        loc = ".".join(str(x) for x in e.get("loc", ()))
        msg = str(e["msg"]).removeprefix("Value error, ")
        got = f" (got {e['input']!r})" if loc and not isinstance(e.get("input"), dict) else ""
        out.append(f"{loc + ': ' if loc else ''}{msg}{got}"[:300])
    return "; ".join(out)


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


class HmiServer:
    """uvicorn serving :func:`build_app` on ``hcfg.host:hcfg.port``, in the foreground or a thread."""

    def __init__(self, hmi: Hmi) -> None:
        import uvicorn

        from cellctl.hmi.transport import uvicorn_config

        self.hmi = hmi
        self.server = uvicorn.Server(uvicorn_config(build_app(hmi), hmi.hcfg))
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        return f"http://{self.hmi.hcfg.host}:{self.hmi.hcfg.port}"

    def run(self) -> None:
        """Serve until SIGINT/SIGTERM."""
        self.server.run()

    def start(self, timeout: float = 20.0) -> HmiServer:
        """Serve in a background thread; returns once the socket is listening."""
        self._thread = threading.Thread(target=self.server.run, name="hmi-http", daemon=True)
        self._thread.start()
        deadline = time.monotonic() + timeout
        while not self.server.started:
            if time.monotonic() > deadline or not self._thread.is_alive():
                raise CellError(f"HMI server did not start on {self.url}")
            time.sleep(0.05)
        return self

    def stop(self) -> None:
        self.server.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout=10)
