"""What a cycle knows (:class:`CycleContext`, the blackboard) and how a step talks to workers
(:class:`StepRun`: every call has a timeout, is recorded, and stops at cancellation)."""

from __future__ import annotations

import copy
import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
import zenoh

from cellctl.bus import keys, topics
from cellctl.bus.rpc import request
from cellctl.config import CellConfig
from cellctl.errors import CellError, WorkerError, WorkerUnavailable
from cellctl.messages import (
    ApproachReply,
    ClassifyReply,
    CommissionResult,
    CycleOutcome,
    DecisionPath,
    ErrorReply,
    EventLevel,
    Intrinsics,
    PlanLookupReply,
    StartMode,
    StartParams,
    StationInfo,
    ViewpointResult,
    WashResult,
    WashRound,
    WireMessage,
)
from cellctl.seen import Verdict
from cellctl.supervisor.recorder import Recorder
from cellctl.surface import SURFACES

if TYPE_CHECKING:  # the daemon imports neither at start: vision pulls OpenCV in
    from cellctl.geometry.catalog import Catalog
    from cellctl.vision.fuse import FusedIdentification
    from cellctl.vision.identify import Identification
    from cellctl.workers.base import Base

__all__ = ["INITIAL_CONTEXT", "Cancelled", "CycleContext", "Identify", "StepRun"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

M = TypeVar("M", bound=WireMessage)


class Cancelled(CellError):
    """The step was cancelled (Stop, Abort, Hold, Suspend, worker lost); its result is void."""


INITIAL_CONTEXT = (
    "cycle_id",
    "mode",
    "params",
    "started",
    "observation_index",
    "identify_attempts",
    "next_viewpoint",
    "viewpoints",
    "classifications",
    "station_index",
    "surface_index",
)
"""Blackboard fields every cycle starts with set; the rest start as ``None`` and are written by steps.

The loader checks each step's ``READS`` against these plus what earlier steps ``WRITE``."""

Identify = Callable[[np.ndarray, Intrinsics, np.ndarray, "Catalog | None"], "Identification"]
"""``identify(image_bgr, intrinsics, T_base_cam, catalog) -> Identification``."""


@dataclass
class CycleContext:
    """The blackboard of one inspection cycle; steps read and write it, one at a time."""

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

    observation_index: int = 0
    identify_attempts: int = 0
    approach: ApproachReply | None = None
    identification: Identification | FusedIdentification | None = None
    bin_type: str | None = None
    T_base_bin: np.ndarray | None = None
    plan: PlanLookupReply | None = None
    planner_job_id: str | None = None
    next_viewpoint: int = 0
    viewpoints: list[ViewpointResult] = field(default_factory=list)
    classifications: dict[int, Future[ClassifyReply]] = field(default_factory=dict)
    verdict: Verdict | None = None
    coverage: float | None = None
    dirt_map: dict[str, Any] | None = None  # JSON for the CycleResult, as recording.dirt_map reads it
    outcome: CycleOutcome | None = None
    reason: str | None = None
    saved_step: str | None = None
    finished: bool = False
    # --- wash_and_verify (steps/washing.py, steps/verifying.py)
    wash_plan: Any = None
    """The round's :class:`cellctl.washing.plan.WashPlan` while it is washed and re-inspected (not on the wire)."""
    wash_rounds: list[WashRound] = field(default_factory=list)
    wash_run: dict[str, Any] = field(default_factory=dict)
    """The running round's counts: sweeps and passes run, sweeps refused, its pictures so far."""
    wash_next_sweep: int = 0
    wash_next_view: int = 0
    wash: WashResult | None = None
    # wash_and_verify in a whole-bin cycle: a round washes from, then re-inspects from, each station
    # it needs (steps/washing.py WashStation); single-station cycles use the one entry None
    wash_phase: str = "wash"
    """``wash`` (running the sweeps station by station) or ``verify`` (re-inspecting) within a round."""
    wash_queue: list[int | None] = field(default_factory=list)
    """Stations still to wash from this round, in order (the head is the one washed or parked for now)."""
    verify_queue: list[int | None] = field(default_factory=list)
    """Stations still to re-inspect from this round, in order."""
    wash_parked: int | None = None
    """The station the base is parked at while washing and re-inspecting (None: single-station)."""
    wash_scan_poses: dict[int, np.ndarray] = field(default_factory=dict)
    """station → T_base_bin the scan's plans were adjusted to (a re-park measures a new one)."""
    wash_station_sweeps: dict[int | None, list[Any]] = field(default_factory=dict)
    """station → this round's PlannedSweeps to run there (absent: plan them at the station's new park)."""
    wash_views: list[ViewpointResult] = field(default_factory=list)
    """The re-inspection views (``wash_round`` set): in the MCAP and the rounds' counts, not in the
    CycleResult's ``viewpoints`` (a whole-bin wash cycle's would pass the 64 KiB wire limit)."""
    # --- reference sets (steps/references.py): written by a commissioning cycle, looked up by the others
    references: Any = None
    """Mode commission: the :class:`cellctl.recording.references.ReferenceSetWriter` the scan stores its views in."""
    decision_path: dict[str, DecisionPath] | None = None
    reference_version: int | None = None
    commission: CommissionResult | None = None
    # --- whole-bin cycle (planner.whole.enabled): the station loop's place and what each station gave
    station_index: int = 0
    """Position in ``station_order`` of the station the cycle is at (Hold/Suspend resume here)."""
    surface_index: int = 0
    """Position in the current station's surfaces (:meth:`station_surfaces`)."""
    stations: list[StationInfo] | None = None
    """The whole-bin plan's stations, from the first lookup; None until then."""
    station_order: list[int] = field(default_factory=list)
    """Station ranks in visiting order (starting where the first park was identified)."""
    whole_plan_id: str | None = None
    modelled_cycle_s: float | None = None
    plans: dict[tuple[int | None, str | None], PlanLookupReply] = field(default_factory=dict)
    """(station, surface) → the plan scanned there; single-station cycles use key (None, None)."""
    bin_poses: dict[int, np.ndarray] = field(default_factory=dict)
    """station → T_base_bin used there (measured, or the planned station pose when carried over)."""
    pose_source: dict[int, str] = field(default_factory=dict)
    T_map_base: np.ndarray | None = None
    """The base's reported pose (its localisation, ApproachReply.base_pose) at the current park; None: no report."""
    T_map_bin: np.ndarray | None = None
    """The bin in the base's map frame, from the latest pose measured with a base report (base_odometry)."""
    station_coverage: dict[tuple[int | None, str | None], float | None] = field(default_factory=dict)
    coverage_by_surface: dict[str, float | None] | None = None
    station_notes: dict[int, str] = field(default_factory=dict)
    step_seconds: dict[str, float] = field(default_factory=dict)
    rpc_seconds: dict[str, float] = field(default_factory=dict)
    rpc_count: int = 0
    _pool: ThreadPoolExecutor | None = None
    _ended: threading.Event = field(default_factory=threading.Event)

    @property
    def whole(self) -> bool:
        """A whole-bin cycle: every station of the newest whole-bin plan, both surfaces."""
        return self.cfg.planner.whole.enabled

    @property
    def surface(self) -> str:
        """The surface inspected now: the current station's, in a whole-bin cycle (external before its
        stations are known); else the Start param, else the config's default."""
        if self.whole:
            surfs = self.station_surfaces()
            return surfs[self.surface_index] if self.surface_index < len(surfs) else SURFACES[0]
        return self.params.surface or self.cfg.planner.surface

    def current_station(self) -> StationInfo | None:
        """The station the whole-bin cycle is at, or None (single-station cycle, or stations not known yet)."""
        if not self.stations or self.station_index >= len(self.station_order):
            return None
        rank = self.station_order[self.station_index]
        return next(s for s in self.stations if s.station == rank)

    def station_surfaces(self, st: StationInfo | None = None) -> list[str]:
        """The surfaces a station has viewpoints for, in :data:`~cellctl.surface.SURFACES` order."""
        st = st if st is not None else self.current_station()
        return [s for s in SURFACES if st is not None and s in st.plans]

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
