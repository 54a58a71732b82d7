"""The HMI web server: pages, the REST API and server-sent events, on FastAPI + uvicorn.

Layout of the process (``cellctl hmi``)::

    CellView     Zenoh client: Status, events → alarms, results; commands by query → Ack
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

import json
import logging
import threading
import time
from collections.abc import Callable
from functools import partial
from typing import Any

from fastapi import FastAPI

from cellctl.config import CellConfig
from cellctl.errors import CellError
from cellctl.hmi.auth import SessionStore
from cellctl.hmi.config import HmiConfig
from cellctl.hmi.link import CellView
from cellctl.hmi.live import LiveCycle, McapTail
from cellctl.hmi.records import CycleRecords, NotFound
from cellctl.hmi.review import Review
from cellctl.hmi.review_api import add_review_routes
from cellctl.hmi.routes import (
    HttpError,
    add_error_handlers,
    add_guard,
    cell_router,
    events_router,
    need_user,
    pages_router,
    records_router,
    session_router,
)
from cellctl.login_throttle import LoginThrottle
from cellctl.messages import now_iso

__all__ = ["Hmi", "HmiServer", "LiveWatcher", "build_app"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

# --- the live cycle -------------------------------------------------------------------------------


class LiveWatcher:
    """Follows the cell's current (or last) cycle log; ``version`` changes when the view does.

    Args:
        on_message: also called with each new log message (the live Foxglove view).
    """

    def __init__(
        self, link: CellView, records: CycleRecords, period_s: float = 0.25, on_message: Callable | None = None
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
        self.link = CellView(cfg, hcfg.stale_s, hcfg.events_kept, reopen_s=max(3 * hcfg.stale_s, 2.0))
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


def build_app(hmi: Hmi) -> FastAPI:
    """The FastAPI application of ``hmi``: the guard (error mapping, security checks) and the routers
    of :mod:`cellctl.hmi.routes`, added in the order the routes are matched and listed."""
    app = FastAPI(
        title="cellctl HMI",
        version="1",
        description="Operator screen and REST API of a cellctl inspection cell (read-only without login).",
        docs_url=None,  # the Swagger page loads its assets from a CDN; the schema is at /openapi.json
        redoc_url=None,
    )
    add_error_handlers(app)
    add_guard(app, hmi.hcfg)
    add_review_routes(app, hmi, partial(need_user, hmi), HttpError)
    for router in (session_router(hmi), cell_router(hmi), events_router(hmi), records_router(hmi), pages_router()):
        app.include_router(router)
    return app


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
