"""What a cycle knows (:class:`CycleContext`: infrastructure, Start inputs and the blackboard's
sub-records, one module each in this package) and how a step talks to workers (:class:`StepRun`:
every call has a timeout, is recorded, and stops at cancellation)."""

from __future__ import annotations

import copy
import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, TypeVar

import numpy as np
import zenoh

from cellctl.bus import keys, topics
from cellctl.bus.rpc import request
from cellctl.config import CellConfig
from cellctl.errors import CellError, WorkerError, WorkerUnavailable
from cellctl.messages import ErrorReply, EventLevel, Intrinsics, StartMode, StartParams, WireMessage
from cellctl.supervisor.context.identity import Identity
from cellctl.supervisor.context.refs import Refs
from cellctl.supervisor.context.result import Result
from cellctl.supervisor.context.scan import Scan
from cellctl.supervisor.context.stations import Stations
from cellctl.supervisor.context.wash import Wash
from cellctl.supervisor.recorder import Recorder
from cellctl.surface import SURFACES, Surface

if TYPE_CHECKING:  # the daemon imports neither at start: vision pulls OpenCV in
    from cellctl.geometry.catalog import Catalog
    from cellctl.vision.identify import Identification
    from cellctl.workers.base import Base

__all__ = ["BLACKBOARD", "INITIAL_CONTEXT", "RECORDS", "Cancelled", "CycleContext", "Identify", "StepRun"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

M = TypeVar("M", bound=WireMessage)


class Cancelled(CellError):
    """The step was cancelled (Stop, Abort, Hold, Suspend, worker lost); its result is void."""


Identify = Callable[[np.ndarray, Intrinsics, np.ndarray, "Catalog | None"], "Identification"]
"""``identify(image_bgr, intrinsics, T_base_cam, catalog) -> Identification``."""

RECORDS: dict[str, type] = {
    "identity": Identity,
    "stations": Stations,
    "scan": Scan,
    "wash": Wash,
    "refs": Refs,
    "result": Result,
}
"""The blackboard's sub-records by their attribute on :class:`CycleContext`; steps declare ``record.field``."""


BLACKBOARD: frozenset[str] = frozenset(f"{name}.{f.name}" for name, rec in RECORDS.items() for f in fields(rec))
"""Every blackboard field a step may declare, as ``record.field``."""


def _initial_context() -> tuple[str, ...]:
    """Every record field with a usable value at the start (a counter, an empty container, a phase)."""
    out = []
    for name, rec in RECORDS.items():
        blank = rec()
        out += [f"{name}.{f.name}" for f in fields(rec) if getattr(blank, f.name) is not None]
    return tuple(out)


INITIAL_CONTEXT: tuple[str, ...] = _initial_context()
"""Blackboard fields (``record.field``) every cycle starts with set; the rest start as ``None`` and are
written by steps. The loader checks each step's ``READS`` against these plus what earlier steps ``WRITE``."""


@dataclass
class CycleContext:
    """One inspection cycle: its infrastructure and Start inputs, and the blackboard its steps share.

    The blackboard is six sub-records, each written by the steps that own it (:data:`RECORDS`);
    a step sees them through :class:`~cellctl.supervisor.context.view.StepView`, which refuses what
    the step did not declare. Behaviours, the supervisor and the result assembly use the context itself.
    """

    cycle_id: str
    cfg: CellConfig
    session: zenoh.Session | None
    log: Recorder
    mode: StartMode = "evaluate"
    params: StartParams = field(default_factory=StartParams)
    user: str | None = None
    """Who sent the Start (``Command.user``)."""
    started: str = ""
    log_rel: str | None = None
    post_event: Callable[[str, str], None] = lambda level, text: None
    identify: Identify | None = None
    catalog: Catalog | None = None
    base: Base | None = None
    """The mobile base (``base.backend``) the approaching step parks through; None: the robot worker alone."""
    saved_step: str | None = None
    finished: bool = False
    step_seconds: dict[str, float] = field(default_factory=dict)
    rpc_seconds: dict[str, float] = field(default_factory=dict)
    rpc_count: int = 0
    # --- the blackboard
    identity: Identity = field(default_factory=Identity)
    stations: Stations = field(default_factory=Stations)
    scan: Scan = field(default_factory=Scan)
    wash: Wash = field(default_factory=Wash)
    refs: Refs = field(default_factory=Refs)
    result: Result = field(default_factory=Result)
    _pool: ThreadPoolExecutor | None = None
    _ended: threading.Event = field(default_factory=threading.Event)

    @property
    def whole(self) -> bool:
        """A whole-bin cycle: every station of the newest whole-bin plan, both surfaces."""
        return self.cfg.planner.whole.enabled

    @property
    def surface(self) -> Surface:
        """The surface inspected now: the current station's, in a whole-bin cycle (external before its
        stations are known); else the Start param, else the config's default."""
        if self.whole:
            surfs = self.stations.station_surfaces()
            return surfs[self.stations.surface_index] if self.stations.surface_index < len(surfs) else SURFACES[0]
        return self.params.surface or self.cfg.planner.surface

    @property
    def pool(self) -> ThreadPoolExecutor:
        """One background thread for work that overlaps robot motion (classification)."""
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"cycle-{self.cycle_id[-6:]}")
        return self._pool

    def shutdown(self) -> None:
        """The cycle ended: void background work (see :meth:`StepRun.detached`) and stop the pool."""
        self._ended.set()
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None


class StepRun:
    """One activation of a step or behaviour: its cancellation flag and its bus calls."""

    def __init__(self, ctx: CycleContext, token: int, name: str) -> None:
        self.ctx = ctx
        self.token = token
        self.name = name
        self.cancelled = threading.Event()

    def detached(self, name: str) -> StepRun:
        """This run's calls for work that outlives the activation (a classification overlapping the
        next move): a Hold or Suspend does not void it, only the end of the cycle does, so the
        resumed cycle still finds its result."""
        run = copy.copy(self)
        run.name = name
        run.cancelled = self.ctx._ended
        return run

    def checkpoint(self) -> None:
        """Raise :class:`Cancelled` if this activation was cancelled."""
        if self.cancelled.is_set():
            raise Cancelled(f"{self.name} cancelled")

    def event(self, level: str, text: str) -> None:
        self.ctx.post_event(level, text)

    def _account(self, account: str | None, dt: float) -> None:
        """Time inside worker requests (refused ones too), per step: what the supervisor did not spend itself."""
        name = account or self.name
        self.ctx.rpc_seconds[name] = self.ctx.rpc_seconds.get(name, 0.0) + dt
        self.ctx.rpc_count += 1

    def call(
        self,
        role: str,
        op: str,
        msg: WireMessage,
        expect: type[M],
        *,
        payload: bytes | None = None,
        timeout: float | None = None,
        key: str | None = None,
        account: str | None = None,
    ) -> tuple[M, bytes | None]:
        """Request ``op`` from the ``role`` worker, recorded in the cycle log.

        Raises:
            Cancelled: before sending, or when the reply arrives after cancellation.
            WorkerUnavailable / WorkerTimeout / WorkerFailed: see :mod:`cellctl.bus.rpc`.

        ``account`` names the timing bucket (default: this step); background calls use their
        own so overlapping time is not subtracted from the step's wall time.
        """
        self.checkpoint()
        if self.ctx.session is None:
            raise WorkerUnavailable(f"no bus session to ask the {role} worker for {op}", role=role)
        k = key or keys.worker_op(self.ctx.cfg.cell_id, role, op)
        t = timeout if timeout is not None else getattr(self.ctx.cfg.supervisor.timeouts, op, None)
        t = t if t is not None else self.ctx.cfg.supervisor.timeouts.default
        self.ctx.log.write_message(topics.request(k), msg)
        t0 = time.perf_counter()
        try:
            reply, raw = request(self.ctx.session, k, msg, expect, timeout=t, payload=payload, role=role)
        except WorkerError as err:
            self._account(account, time.perf_counter() - t0)
            self.ctx.log.write_message(topics.reply(k), ErrorReply(kind=type(err).__name__, reason=str(err)))
            self.ctx.log.event(int(EventLevel.error), f"{role}/{op}: {err}")
            raise
        dt = time.perf_counter() - t0
        log.debug("%s/%s in %.1f ms", role, op, dt * 1e3)
        self._account(account, dt)
        self.ctx.log.write_message(topics.reply(k), reply)
        self.checkpoint()
        return reply, raw
