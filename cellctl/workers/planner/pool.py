"""The planner pool: several planner workers (on the compute host) serving several cells.

Claim protocol: **one queue owner + pull claims + leases held by the claimant's liveliness.**

* The job queue (:class:`JobQueue`) runs in the compute host's router process
  (``cellctl router`` with a ``pool:`` section). It serves ``cell/*/planner/jobs`` for every
  cell it is configured for, exactly the contract a cell's supervisor already speaks
  (:class:`PlanJobRequest` → queued job id, :class:`PlanJobQuery` → state), and declares
  ``cell/<id>/alive/planner/pool`` for each of them while at least one worker is alive.
* A pool worker (``cellctl worker planner --backend pool``) declares
  ``pool/planner/alive/<instance>`` and, while idle, asks ``pool/planner/claim`` for a job
  (:class:`PoolClaim`; the query waits up to ``claim_wait_s`` for one). One thread of the
  queue pairs claims with jobs, so a job is handed to exactly one claimant; the queue refuses
  a claimant whose token it does not see.
* The claim is a lease: it holds while the claimant's liveliness token lives. When the token
  goes (the worker died, froze past the link lease, or its link was cut) the queue puts the
  job back at the head of the queue, or fails it visibly after ``max_attempts`` claims: the
  bound is the link lease plus one dispatch tick.
* The worker reports the result on ``pool/planner/done`` (:class:`PoolDone`, retried until the
  queue answers). A result for a job that was already done (a worker that came back after its
  lease was given away) is counted in ``planned_twice``, never recorded as a second job.
* Pool workers also plan any cell's wash rounds (``cell/*/planner/wash_plan``, the same
  :func:`cellctl.washing.service.wash_plan_reply` as a cell's own planner worker; one worker
  answers each request, the bus's best-matching query target).
* Pool workers answer the plan-cache lookups of every cell (``cell/*/planner/lookup``) from
  one plans folder, so a plan made for cell A's bin type is found by cell B when the bin
  stands at the same pose (within the tolerance) before the same robot model, and not
  otherwise: :func:`cellctl.planning.adjust.lookup_plan` compares mesh hash, robot model id
  and pose.

Why not a queryable that answers only when idle: every submit would be a two-phase offer
and accept between the submitter (the cell's supervisor, which we do not want to change) and
the workers; and Zenoh has no atomic compare-and-set for a shared "queue key". One owner
serialises claims without consensus; it is a single point, but it lives on the compute host
with the workers, so it fails together with them, and its job records (``jobs_dir``)
survive its restart: queued jobs stay queued, a running job stays with its claimant if that
worker's token comes back within a grace period, else it is re-queued.
"""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
import uuid
from collections import deque
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from cellctl.bus import keys
from cellctl.bus.codec import MAX_PAYLOAD_BYTES, decode, decode_as, encode
from cellctl.errors import CellError, ConfigError, ProtocolError
from cellctl.messages import (
    ErrorReply,
    PlanJobQuery,
    PlanJobReply,
    PlanJobRequest,
    PoolAssignment,
    PoolClaim,
    PoolDone,
    PoolStats,
)

__all__ = ["JobQueue", "PoolJob", "run_pool_worker"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

_TICK_S = 0.05
_RESTART_GRACE_S = 3.0
"""After a restart of the queue, how long a running job waits for its claimant's token."""


@dataclass
class PoolJob:
    """One planning job as the queue records it (``<jobs_dir>/<job_id>.json``)."""

    job_id: str
    cell_id: str
    request: dict[str, Any]
    state: str = "queued"  # queued | running | done | failed
    attempt: int = 0
    claimant: str | None = None
    plan_id: str | None = None
    reason: str | None = None
    planned_by: list[str] = field(default_factory=list)
    submitted_at: float = 0.0


@dataclass
class _Counters:
    submitted: int = 0
    planned: int = 0
    failed: int = 0
    requeued: int = 0
    planned_twice: int = 0
    per_worker: dict[str, int] = field(default_factory=dict)


@dataclass
class _Event:
    kind: str  # jobs | claim | done | stats | alive | gone
    query: Any = None
    key: str = ""
    payload: bytes = b""


class JobQueue:
    """The pool's job queue in an open (router) session; all state changes on one thread.

    Args:
        session: the compute host's router session (never ACL-filtered).
        cells: cells whose jobs this pool takes (their supervisors see ``alive/planner/pool``).
        jobs_dir: where job records are kept across restarts.
        max_attempts: claims per job before it fails visibly.
        claim_wait_s: longest a claim waits for a job before it is answered "none".
    """

    def __init__(
        self,
        session: zenoh.Session,
        cells: list[str],
        jobs_dir: Path,
        max_attempts: int = 2,
        claim_wait_s: float = 1.0,
    ) -> None:
        self.session = session
        self.cells = [keys.check_cell_id(c) for c in cells]
        self.jobs_dir = Path(jobs_dir)
        self.max_attempts = max_attempts
        self.claim_wait_s = claim_wait_s
        self.jobs: dict[str, PoolJob] = {}
        self._queue: deque[str] = deque()
        self._claims: deque[tuple[Any, str, float]] = deque()
        self._alive: set[str] = set()
        self._tokens: list[Any] = []
        self._grace_until = 0.0
        self.stats = _Counters()
        self._inbox: queue.Queue[_Event] = queue.Queue()
        self._stop = threading.Event()
        self._decls: list[Any] = []
        self._thread = threading.Thread(target=self._run, name="pool-queue", daemon=True)

    # --- life cycle ---------------------------------------------------------------------

    def start(self) -> JobQueue:
        self.jobs_dir.mkdir(parents=True, exist_ok=True)
        self._load()
        put = self._inbox.put
        # Callbacks only enqueue: the one queue thread does all the work, in arrival order.
        self._decls = [
            self.session.declare_queryable(
                keys.planner_jobs_any(), lambda q: put(_Event("jobs", q, str(q.key_expr), _body(q))), complete=True
            ),
            self.session.declare_queryable(keys.pool_claim(), lambda q: put(_Event("claim", q, payload=_body(q)))),
            self.session.declare_queryable(keys.pool_done(), lambda q: put(_Event("done", q, payload=_body(q)))),
            self.session.declare_queryable(keys.pool_stats(), lambda q: put(_Event("stats", q))),
            self.session.liveliness().declare_subscriber(keys.pool_alive(), self._on_alive, history=True),
        ]
        self._thread.start()
        log.info("planner pool queue for cells %s, %d job(s) recovered", self.cells, len(self._queue))
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        for d in self._decls:
            d.undeclare()
        self._set_cell_tokens(False)
        self._decls = []

    def __enter__(self) -> JobQueue:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _on_alive(self, sample: Any) -> None:
        gone = sample.kind == zenoh.SampleKind.DELETE
        self._inbox.put(_Event("gone" if gone else "alive", key=str(sample.key_expr)))

    # --- records ------------------------------------------------------------------------

    def _save(self, job: PoolJob) -> None:
        from cellctl.planning.planfile import write_document  # json/hashlib only: light

        try:
            write_document(asdict(job), self.jobs_dir / f"{job.job_id}.json")
        except CellError as err:  # the queue goes on; a restart would lose this job's state
            log.warning("cannot write pool job record %s: %s", job.job_id, err)

    def _load(self) -> None:
        from cellctl.planning.planfile import read_document

        recovered = []
        for path in sorted(self.jobs_dir.glob("*.json")):
            try:
                job = PoolJob(**read_document(path))
            except (CellError, TypeError) as err:
                log.warning("pool job record %s skipped: %s", path, err)
                continue
            self.jobs[job.job_id] = job
            if job.state in ("queued", "running"):
                recovered.append(job)
        for job in sorted(recovered, key=lambda j: j.submitted_at):
            if job.state == "queued":
                self._queue.append(job.job_id)
        self._grace_until = time.monotonic() + _RESTART_GRACE_S
        jobs = list(self.jobs.values())
        self.stats.submitted = len(jobs)
        self.stats.planned = sum(j.state == "done" for j in jobs)
        self.stats.failed = sum(j.state == "failed" for j in jobs)
        self.stats.planned_twice = sum(max(0, len(j.planned_by) - 1) for j in jobs)
        for j in jobs:
            if j.state == "done" and j.planned_by:
                self.stats.per_worker[j.planned_by[0]] = self.stats.per_worker.get(j.planned_by[0], 0) + 1

    # --- the queue thread ---------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                ev = self._inbox.get(timeout=_TICK_S)
            except queue.Empty:
                ev = None
            if ev is not None:
                try:
                    self._handle(ev)
                except Exception:  # one bad event must not stop the queue
                    log.exception("pool queue: %s event failed", ev.kind)
                finally:
                    if ev.query is not None and ev.kind != "claim":
                        ev.query.drop()
            self._dispatch()

    def _handle(self, ev: _Event) -> None:
        if ev.kind == "alive":
            self._worker_up(ev.key.rsplit("/", 1)[-1])
        elif ev.kind == "gone":
            self._worker_lost(ev.key.rsplit("/", 1)[-1])
        elif ev.kind == "jobs":
            self._reply(ev.query, lambda: self._on_jobs(ev.key, ev.payload))
        elif ev.kind == "done":
            self._reply(ev.query, lambda: self._on_done(decode_as(PoolDone, ev.payload, MAX_PAYLOAD_BYTES)))
        elif ev.kind == "stats":
            self._reply(ev.query, self._stats)
        elif ev.kind == "claim":
            try:
                claim = decode_as(PoolClaim, ev.payload, MAX_PAYLOAD_BYTES)
            except CellError as err:
                ev.query.reply_err(encode(ErrorReply(kind=type(err).__name__, reason=str(err))))
                ev.query.drop()
                return
            if claim.instance not in self._alive:
                # A claim without a lease cannot be taken back if the claimant vanishes.
                ev.query.reply(keys.pool_claim(), encode(PoolAssignment(reason="no liveliness token seen")))
                ev.query.drop()
                return
            self._claims.append((ev.query, claim.instance, time.monotonic() + self.claim_wait_s))

    def _reply(self, query: Any, fn: Any) -> None:
        try:
            query.reply(query.key_expr, encode(fn()))
        except CellError as err:
            query.reply_err(encode(ErrorReply(kind=type(err).__name__, reason=str(err))))

    def _on_jobs(self, key: str, payload: bytes) -> PlanJobReply:
        cell = keys.cell_from_key(key)
        if cell not in self.cells:
            raise ConfigError(f"cell {cell!r} is not served by this planner pool; it serves {self.cells}")
        msg = decode(payload, MAX_PAYLOAD_BYTES)
        if isinstance(msg, PlanJobQuery):
            job = self.jobs.get(msg.job_id)
            if job is None or job.cell_id != cell:
                return PlanJobReply(job_id=msg.job_id, state="failed", reason=f"unknown job {msg.job_id!r}")
            return _job_reply(job)
        if not isinstance(msg, PlanJobRequest):
            raise ProtocolError(f"expected cellctl/PlanJobRequest or cellctl/PlanJobQuery, got {msg.type}")
        job = PoolJob(
            job_id=f"{cell}-{uuid.uuid4().hex[:10]}",
            cell_id=cell,
            request=msg.model_dump(mode="json"),
            submitted_at=time.time(),
        )
        self.jobs[job.job_id] = job
        self._queue.append(job.job_id)
        self.stats.submitted += 1
        self._save(job)
        log.info("job %s queued for cell %s (%s)", job.job_id, cell, msg.bin_type)
        return _job_reply(job)

    def _on_done(self, done: PoolDone) -> PlanJobReply:
        job = self.jobs.get(done.job_id)
        if job is None:
            return PlanJobReply(job_id=done.job_id, state="failed", reason=f"unknown job {done.job_id!r}")
        if job.state in ("done", "failed"):
            if done.state == "done" and done.instance not in job.planned_by:
                # The lease was given away and both claimants planned it: count it, keep the first.
                self.stats.planned_twice += 1
                job.planned_by.append(done.instance)
                self._save(job)
            return _job_reply(job)
        if job.state == "queued" and job.job_id in self._queue:
            # re-queued after a lost lease and nobody took it yet: this result counts
            self._queue.remove(job.job_id)
        job.state, job.plan_id, job.reason = done.state, done.plan_id, done.reason
        job.claimant = None
        if done.state == "done":
            job.planned_by.append(done.instance)
            self.stats.planned += 1
            self.stats.per_worker[done.instance] = self.stats.per_worker.get(done.instance, 0) + 1
        else:
            self.stats.failed += 1
        self._save(job)
        log.info("job %s %s by %s", job.job_id, done.state, done.instance)
        return _job_reply(job)

    def _stats(self) -> PoolStats:
        return PoolStats(
            **asdict(self.stats),
            queued=len(self._queue),
            running=sum(j.state == "running" for j in self.jobs.values()),
            workers=sorted(self._alive),
        )

    def _worker_up(self, instance: str) -> None:
        self._alive.add(instance)
        self._set_cell_tokens(True)

    def _worker_lost(self, instance: str) -> None:
        self._alive.discard(instance)
        self._claims = deque(c for c in self._claims if c[1] != instance)
        for job in self.jobs.values():
            if job.state == "running" and job.claimant == instance:
                self._requeue(job, f"planner worker {instance} lost mid-job")
        if not self._alive:
            self._set_cell_tokens(False)

    def _requeue(self, job: PoolJob, why: str) -> None:
        job.claimant = None
        if job.attempt >= self.max_attempts:
            job.state = "failed"
            job.reason = f"{why} (attempt {job.attempt} of {self.max_attempts}); job failed"
            self.stats.failed += 1
            log.warning("job %s failed: %s", job.job_id, job.reason)
        else:
            job.state = "queued"
            job.reason = f"{why}; re-queued"
            self._queue.appendleft(job.job_id)
            self.stats.requeued += 1
            log.warning("job %s re-queued: %s", job.job_id, why)
        self._save(job)

    def _dispatch(self) -> None:
        now = time.monotonic()
        if now > self._grace_until:
            for job in self.jobs.values():
                if job.state == "running" and job.claimant not in self._alive:
                    self._requeue(job, f"planner worker {job.claimant} not back after a restart of the queue")
            self._grace_until = float("inf")
        while self._queue and self._claims:
            query, instance, _ = self._claims.popleft()
            if instance not in self._alive:
                query.drop()
                continue
            job = self.jobs[self._queue.popleft()]
            job.state, job.claimant = "running", instance
            job.attempt += 1
            self._save(job)
            query.reply(
                keys.pool_claim(),
                encode(
                    PoolAssignment(
                        job_id=job.job_id,
                        cell_id=job.cell_id,
                        attempt=job.attempt,
                        request=PlanJobRequest.model_validate(job.request),
                    )
                ),
            )
            query.drop()
            log.info("job %s claimed by %s (attempt %d)", job.job_id, instance, job.attempt)
        while self._claims and self._claims[0][2] < now:
            query, _, _ = self._claims.popleft()
            query.reply(keys.pool_claim(), encode(PoolAssignment()))
            query.drop()

    def _set_cell_tokens(self, up: bool) -> None:
        if up and not self._tokens:
            self._tokens = [
                self.session.liveliness().declare_token(keys.alive(c, "planner", "pool")) for c in self.cells
            ]
        elif not up:
            for t in self._tokens:
                t.undeclare()
            self._tokens = []


def _body(query: Any) -> bytes:
    return query.payload.to_bytes() if query.payload is not None else b""


def _job_reply(job: PoolJob) -> PlanJobReply:
    state = job.state if job.state in ("queued", "running", "done", "failed") else "failed"
    return PlanJobReply(job_id=job.job_id, state=state, plan_id=job.plan_id, reason=job.reason)  # type: ignore[arg-type]


# --- the worker side -------------------------------------------------------------------


def run_pool_worker(cfg: Any, stop_event: threading.Event, instance: str | None = None) -> None:
    """A pool worker: claim jobs from the pool's queue, plan them, answer every cell's lookups.

    Blocks until ``stop_event`` is set. The plans folder (``planner.plans_dir``) is the pool's
    shared plan cache: every worker of the pool must see the same one.

    Raises:
        ConfigError: no Zenoh router reachable.
    """
    from cellctl.bus.session import open_session
    from cellctl.messages import PlanJobProgress, PlanLookupRequest
    from cellctl.workers._server import WorkerServer
    from cellctl.workers.planner import PlannerService

    name = instance or f"p{os.getpid()}-{uuid.uuid4().hex[:4]}"
    session = open_session(cfg, "client")
    current = {"cell": cfg.cell_id}
    try:

        def publish(job_id: str, msg: PlanJobProgress) -> None:
            session.put(keys.planner_job_progress(current["cell"], job_id), encode(msg))

        service = PlannerService(cfg, name, publish)
        server = WorkerServer(session, cfg.cell_id, "planner", instance=name)
        server.serve("lookup", PlanLookupRequest, service.on_lookup, key=keys.planner_lookup_any())
        from cellctl.messages import WashPlanRequest
        from cellctl.washing.service import MeshCache, wash_plan_reply

        # any cell's wash rounds, beside the jobs: a wash plan is seconds, asked for mid-cycle
        meshes = MeshCache(cfg)
        server.serve(
            "wash_plan",
            WashPlanRequest,
            lambda r, _: wash_plan_reply(cfg, meshes, r),
            key=keys.planner_wash_plan_any(),
        )
        token = session.liveliness().declare_token(keys.pool_alive(name))
        log.info("pool worker %s claiming on %s", name, keys.pool_claim())
        try:
            while not stop_event.is_set():
                job = _claim(session, name)
                if job is None:
                    stop_event.wait(0.2)
                    continue
                current["cell"] = job.cell_id or cfg.cell_id
                assert job.job_id is not None and job.request is not None
                service.run_job(job.job_id, job.request)
                st = service.job_state(job.job_id)
                _report(
                    session,
                    PoolDone(
                        job_id=job.job_id, instance=name, state=_final(st.state), plan_id=st.plan_id, reason=st.reason
                    ),
                    stop_event,
                )
        finally:
            token.undeclare()
            server.close()
            service.close()
    finally:
        session.close()


def _final(state: str) -> str:
    return "done" if state == "done" else "failed"


def _claim(session: zenoh.Session, name: str) -> PoolAssignment | None:
    """One claim; None when the queue has no job for us (or cannot be reached: retried)."""
    try:
        replies = list(session.get(keys.pool_claim(), payload=encode(PoolClaim(instance=name)), timeout=5.0))
    except Exception as err:  # the link may be down; the caller retries
        log.debug("claim failed: %s", err)
        return None
    for r in replies:
        if r.ok is None:
            continue
        try:
            a = decode_as(PoolAssignment, r.ok.payload.to_bytes(), MAX_PAYLOAD_BYTES)
        except CellError as err:
            log.warning("bad assignment from the pool queue: %s", err)
            continue
        if a.job_id is not None and a.request is not None:
            return a
    return None


def _report(session: zenoh.Session, done: PoolDone, stop_event: threading.Event, limit_s: float = 120.0) -> None:
    """Deliver a result until the queue answers (a cut link must not lose a finished job)."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline and not stop_event.is_set():
        try:
            for r in session.get(keys.pool_done(), payload=encode(done), timeout=5.0):
                if r.ok is not None:
                    return
        except Exception as err:  # retried below
            log.debug("done report failed: %s", err)
        stop_event.wait(0.5)
    log.error("job %s result could not be delivered to the pool queue within %g s", done.job_id, limit_s)
