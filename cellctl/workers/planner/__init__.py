"""Planner worker: offline planning jobs and plan-cache lookups over Zenoh.

Ops (``cellctl worker planner``):

* ``cell/<id>/planner/jobs``: :class:`PlanJobRequest` → :class:`PlanJobReply` (queued, job id);
  :class:`PlanJobQuery` → :class:`PlanJobReply` (state). Progress per stage is published on
  ``cell/<id>/planner/jobs/<job>/progress`` as :class:`PlanJobProgress`. The finished plan is
  written atomically into ``planner.plans_dir``; a worker dying mid-job leaves no plan file,
  and its job record (``<plans_dir>/jobs/<job>.json``) reads as failed to any other worker
  on the same host.
* ``cell/<id>/planner/lookup``: :class:`PlanLookupRequest` → :class:`PlanLookupReply`: cache
  lookup + pose tolerance + IK/collision re-check at the measured pose, so the supervisor
  never imports OMPL/trimesh/open3d.
* ``cell/<id>/planner/wash_plan``: :class:`~cellctl.messages.WashPlanRequest` →
  :class:`~cellctl.messages.WashPlanReply` (:mod:`cellctl.washing.service`), for the same reason.

Several workers may serve the same cell (each with its own liveliness instance name). A planner
pool serving several cells from the compute host (``--backend pool``, one job to exactly one
worker, one plan cache) is :mod:`cellctl.workers.planner.pool`.
"""

from __future__ import annotations

import logging
import os
import queue
import socket
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from cellctl.config import CellConfig
from cellctl.errors import CellError, ConfigError, PlanningError
from cellctl.messages import (
    PlanJobProgress,
    PlanJobQuery,
    PlanJobReply,
    PlanJobRequest,
    PlanLookupReply,
    PlanLookupRequest,
    PlannedViewpoint,
    PoseMsg,
    StationInfo,
)

__all__ = ["BACKENDS", "PlannerService", "run_worker"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

BACKENDS = ("local", "pool")
"""``local``: serves this cell's keys; ``pool``: claims jobs from a planner pool's queue (pool.py)."""


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class PlannerService:
    """Job queue, job records, lookups; independent of the bus (``publish`` is injected).

    Args:
        cfg: cell config (planner section, catalog).
        instance: this worker's instance name.
        publish: ``publish(job_id, PlanJobProgress)``; None → progress is not published.
    """

    def __init__(self, cfg: CellConfig, instance: str, publish: Any = None) -> None:
        from cellctl.planning.robot import RobotModel

        self.cfg = cfg
        self.instance = instance
        self.publish = publish
        self.plans_dir = cfg.path(cfg.planner.plans_dir)
        self.jobs_dir = self.plans_dir / "jobs"
        self.robot = RobotModel.from_config(cfg)
        self._meshes: dict[str, Any] = {}
        self._queue: queue.Queue[tuple[str, PlanJobRequest] | None] = queue.Queue()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run_jobs, name="planner-jobs", daemon=True)
        self._thread.start()

    # --- job records ----------------------------------------------------------------------

    def _record_path(self, job_id: str) -> Path:
        if not job_id.replace("-", "").isalnum():
            raise PlanningError(f"job id {job_id!r} is invalid: expected letters, digits and '-'")
        return self.jobs_dir / f"{job_id}.json"

    def _write_record(self, job_id: str, **fields: Any) -> None:
        from cellctl.planning.planfile import write_document  # atomic, hashed JSON write

        rec = {"job_id": job_id, "instance": self.instance, "pid": os.getpid(), "host": socket.gethostname(), **fields}
        try:
            write_document(rec, self._record_path(job_id))
        except CellError as err:  # a record is a convenience; the job goes on
            log.warning("cannot write job record %s: %s", job_id, err)

    def job_state(self, job_id: str) -> PlanJobReply:
        """State of a job from its record; running jobs of a dead worker on this host are failed."""
        from cellctl.planning.planfile import read_document

        try:
            rec = read_document(self._record_path(job_id))
        except CellError as err:
            return PlanJobReply(job_id=job_id, state="failed", reason=f"unknown job {job_id!r}: {err}")
        state = rec.get("state", "failed")
        if (
            state in ("queued", "running")
            and rec.get("host") == socket.gethostname()
            and not _pid_alive(int(rec["pid"]))
        ):
            return PlanJobReply(
                job_id=job_id, state="failed", reason=f"planner worker {rec.get('instance')} (pid {rec['pid']}) died"
            )
        return PlanJobReply(job_id=job_id, state=state, plan_id=rec.get("plan_id"), reason=rec.get("reason"))

    # --- ops ----------------------------------------------------------------------------

    def on_jobs(self, req: PlanJobRequest | PlanJobQuery, _payload: bytes | None) -> PlanJobReply:
        if isinstance(req, PlanJobQuery):
            return self.job_state(req.job_id)
        from cellctl.geometry.catalog import load_catalog

        try:
            names = load_catalog(self.cfg.path(self.cfg.catalog), verify_meshes=False).names
        except ConfigError as err:
            raise PlanningError(f"cannot read the bin catalog: {err}") from err
        if req.bin_type not in names:
            raise PlanningError(f"bin type {req.bin_type!r} is unknown; the catalog has {names}")
        job_id = f"{self.instance}-{uuid.uuid4().hex[:8]}"
        self._write_record(job_id, state="queued", request=req.model_dump(mode="json"))
        self._queue.put((job_id, req))
        self._progress(job_id, "queued", 0.0, "queued")
        return PlanJobReply(job_id=job_id, state="queued")

    def _mesh(self, bin_type: str) -> Any:
        from cellctl.planning.mesh import load_catalog_mesh

        with self._lock:
            if bin_type not in self._meshes:
                self._meshes[bin_type] = load_catalog_mesh(self.cfg.path(self.cfg.catalog), bin_type)
            return self._meshes[bin_type]

    def on_lookup(self, req: PlanLookupRequest, _payload: bytes | None) -> PlanLookupReply:
        from cellctl.planning.adjust import lookup_plan

        tol = self.cfg.planner.tolerance
        mesh = self._mesh(req.bin_type)
        try:
            res = lookup_plan(
                self.plans_dir,
                req.bin_type,
                req.surface,
                req.bin_pose.matrix(),
                mesh,
                self.robot,
                tol.translation_mm,
                tol.rotation_deg,
                use_all=req.all_reachable,
            )
        except CellError:
            raise
        except Exception as err:  # a cache file that passed the checks still breaks the adjustment
            # A broken cache costs a replan, not the cycle: answer a miss that says why.
            log.exception("plan cache lookup for %s/%s failed", req.bin_type, req.surface)
            return PlanLookupReply(hit=False, reason=f"plan cache lookup failed ({type(err).__name__}: {err}); replan")
        whole: dict[str, Any] = {}
        if req.whole:
            whole = self._whole_stations(req.bin_type, mesh, req.bin_pose.matrix())
            if not whole["stations"]:
                # no whole-bin plan: replan the whole bin, not one station; an empty one (no station
                # sees the bin) is named, so the cycle fails with its reason instead of replanning again
                return PlanLookupReply(
                    hit=False,
                    reason=whole["reason"],
                    mesh_faces=int(len(mesh.faces)),
                    whole_plan_id=whole.get("plan_id"),
                )
        return PlanLookupReply(
            hit=res.hit,
            reason=res.reason,
            plan_id=res.plan_id,
            viewpoints=[
                PlannedViewpoint(
                    index=v.index,
                    camera_pose=PoseMsg.from_matrix(v.T_base_cam),
                    joints=[float(x) for x in v.q],
                    faces=list(v.faces),
                )
                for v in res.viewpoints
            ],
            coverage=res.coverage if res.hit else None,
            adjusted=res.adjusted,
            translation_mm=res.translation_mm,
            rotation_deg=res.rotation_deg,
            mesh_faces=int(len(mesh.faces)),
            whole_plan_id=whole.get("plan_id"),
            stations=whole.get("stations", []),
            station=whole.get("station"),
            cycle_time_s=whole.get("cycle_time_s"),
        )

    def _whole_stations(self, bin_type: str, mesh: Any, T_base_bin: Any) -> dict[str, Any]:
        """The newest usable whole-bin record of ``bin_type``: its stations and the one nearest the measured pose.

        Usable: made for this mesh and robot model, with every station plan present in the cache
        (a record whose plans were deleted would send the cycle to stations it cannot scan).
        """
        from cellctl.geometry.catalog import load_catalog
        from cellctl.geometry.transforms import invert, pose_error
        from cellctl.planning.planfile import _safe, read_document
        from cellctl.planning.whole import WHOLE_FORMAT
        from cellctl.sim.scene import n_observation_poses, observation_T_bin_cam

        folder = self.plans_dir / _safe(bin_type) / "whole"
        rid = self.robot.model_id()
        usable: list[dict[str, Any]] = []
        why = f"no whole-bin plan for bin type {bin_type!r}"
        for f in sorted(folder.glob("*.json")) if folder.is_dir() else []:
            try:
                d = read_document(f)
            except CellError as err:
                log.warning("plan cache: skipping whole-bin record %s", err)
                continue
            if d.get("format") != WHOLE_FORMAT or d.get("bin_type") != bin_type:
                continue
            if d.get("mesh_sha256") != mesh.sha256 or d.get("robot_model_id") != rid:
                why = f"whole-bin plan {d.get('plan_id')} was made for another mesh or robot model; replan"
                continue
            here = self.plans_dir / _safe(bin_type)
            gone = [
                pid
                for st in d["stations"]
                for surf, pid in st["plans"].items()
                if st["viewpoints"].get(surf) and not (here / surf / f"{pid}.json").is_file()
            ]
            if gone:
                why = f"whole-bin plan {d.get('plan_id')} misses station plan(s) {gone[:3]} in the cache; replan"
                continue
            usable.append(d)
        if not usable:
            return {"stations": [], "reason": why}
        d = max(usable, key=lambda r: r.get("created", ""))
        if not d["stations"]:
            return {
                "stations": [],
                "plan_id": d["plan_id"],
                "reason": f"whole-bin plan {d['plan_id']} has no station: {d.get('reason') or 'none was usable'}",
            }
        bt = load_catalog(self.cfg.path(self.cfg.catalog), verify_meshes=False).get(bin_type)
        obs = [observation_T_bin_cam(bt, k) for k in range(n_observation_poses())]
        stations: list[StationInfo] = []
        errors: list[float] = []
        tol = self.cfg.planner.tolerance
        for st in d["stations"]:
            T_bin_base = np.asarray(st["T_bin_base"], dtype=float)
            ident = st.get("identify")
            k_obs = None
            if ident is not None:
                T = np.asarray(ident["T_bin_cam"], dtype=float)
                k_obs = min(range(len(obs)), key=lambda k: float(np.abs(obs[k] - T).max()))
            surfaces = {s: pid for s, pid in st["plans"].items() if st["viewpoints"].get(s)}
            stations.append(
                StationInfo(
                    station=int(st["rank"]),
                    base_pose=PoseMsg.from_matrix(T_bin_base, "bin"),
                    observation_index=k_obs,
                    identify_reason=st.get("identify_reason"),
                    plans=surfaces,
                    viewpoints={s: int(st["viewpoints"][s]) for s in surfaces},
                )
            )
            dt, dr = pose_error(invert(T_bin_base), T_base_bin)
            errors.append(dt * 1000.0 / tol.translation_mm + float(np.degrees(dr)) / tol.rotation_deg)
        return {
            "plan_id": d["plan_id"],
            "stations": stations,
            "station": stations[int(np.argmin(errors))].station,
            "cycle_time_s": d.get("cycle_time_s"),
        }

    # --- the job thread -------------------------------------------------------------------

    def _progress(
        self, job_id: str, stage: str, frac: float, state: str, message: str | None = None, plan_id: str | None = None
    ) -> None:
        if self.publish is None:
            return
        try:
            self.publish(
                job_id,
                PlanJobProgress(
                    job_id=job_id, stage=stage, fraction=frac, state=state, message=message, plan_id=plan_id
                ),
            )
        except Exception as err:  # progress is best effort, the job goes on
            log.debug("progress publish failed: %s", err)

    def _run_jobs(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            job_id, req = item
            self.run_job(job_id, req)

    def run_job(self, job_id: str, req: PlanJobRequest) -> None:
        """Plan one job (blocking), write the plan into the cache and the job record."""
        import dataclasses

        from cellctl.geometry.camera import CameraModel
        from cellctl.geometry.transforms import invert
        from cellctl.planning.pipeline import make_plan
        from cellctl.planning.plan import PlanParams
        from cellctl.planning.planfile import plan_path, write_plan

        self._write_record(job_id, state="running", request=req.model_dump(mode="json"))
        last = [0.0]

        def progress(stage: str, frac: float, msg: str) -> None:
            now = time.monotonic()
            if frac in (0.0, 1.0) or now - last[0] > 0.2:  # rate-limit the bus traffic
                last[0] = now
                self._progress(job_id, stage, frac, "running", msg or None)

        try:
            params = PlanParams(
                surface=req.surface,
                seed_pct=req.seed_pct,
                mode=req.mode,
                seed=req.seed,
                q_start=tuple(req.q_start) if req.q_start is not None else None,
                camera=CameraModel.from_config(self.cfg.camera),  # the camera the cycle will capture with
            )
            mesh = self._mesh(req.bin_type)
            if req.whole:
                plan = self._whole(job_id, req, mesh, params, progress)
            else:
                T_bin_base = invert(req.bin_pose.matrix())
                plan = make_plan(mesh, T_bin_base, params, self.robot, bin_type=req.bin_type, progress=progress)
                plan = dataclasses.replace(plan, job_id=job_id)
                write_plan(plan, plan_path(self.plans_dir, plan))
        except Exception as err:  # a failed job must not kill the worker
            reason = f"{type(err).__name__}: {err}"
            log.warning("job %s failed: %s", job_id, reason)
            self._write_record(job_id, state="failed", reason=reason)
            self._progress(job_id, "failed", 1.0, "failed", reason)
            return
        warning = None
        if req.whole:  # a bin no plan sees enough of: said when it is planned, not only by `incomplete` cycles
            from cellctl.seen import whole_plan_warning

            warning = whole_plan_warning(plan, self.cfg.classifier.verdict.min_seen_fraction)
            if warning:
                log.warning("job %s: %s", job_id, warning)
        self._write_record(job_id, state="done", plan_id=plan.plan_id, reason=plan.reason or warning)
        self._progress(job_id, "done", 1.0, "done", plan.reason or warning, plan_id=plan.plan_id)
        log.info("job %s done: plan %s", job_id, plan.plan_id)

    def _whole(self, job_id: str, req: PlanJobRequest, mesh: Any, params: Any, progress: Any) -> Any:
        """A whole-bin job: stations and both surfaces; every station plan lands in the cache."""
        from cellctl.geometry.catalog import load_catalog
        from cellctl.planning.whole import WholeParams, plan_whole, write_whole

        bin_type = load_catalog(self.cfg.path(self.cfg.catalog), verify_meshes=False).get(req.bin_type)
        wp = WholeParams.for_cell(self.cfg, params)  # the arm's own speed and acceleration fractions
        plan = plan_whole(mesh, wp, self.robot, bin_type=bin_type, progress=progress, job_id=job_id)
        write_whole(plan, self.plans_dir)
        return plan

    def close(self) -> None:
        self._queue.put(None)
        self._thread.join(timeout=1.0)


def run_worker(cfg: CellConfig, backend: str | None, stop_event: threading.Event) -> None:
    """Serve planner jobs and lookups until ``stop_event`` is set (blocking).

    Raises:
        ConfigError: unknown backend or no Zenoh router reachable.
    """
    from cellctl.bus import keys
    from cellctl.bus.codec import encode
    from cellctl.bus.session import open_session
    from cellctl.workers._server import WorkerServer

    name = backend or "local"
    if name not in BACKENDS:
        raise ConfigError(f"planner backend {name!r} is unknown; expected one of {list(BACKENDS)}")
    if name == "pool":
        from cellctl.workers.planner.pool import run_pool_worker

        run_pool_worker(cfg, stop_event)
        return
    instance = f"p{os.getpid()}-{uuid.uuid4().hex[:4]}"
    session = open_session(cfg, "client")
    try:

        def publish(job_id: str, msg: PlanJobProgress) -> None:
            session.put(keys.planner_job_progress(cfg.cell_id, job_id), encode(msg))

        service = PlannerService(cfg, instance, publish)
        server = WorkerServer(session, cfg.cell_id, "planner", instance=instance)
        server.serve("jobs", (PlanJobRequest, PlanJobQuery), service.on_jobs, key=keys.planner_jobs(cfg.cell_id))
        server.serve("lookup", PlanLookupRequest, service.on_lookup)
        from cellctl.messages import WashPlanRequest
        from cellctl.washing.service import MeshCache, wash_plan_reply

        meshes = MeshCache(cfg)
        server.serve("wash_plan", WashPlanRequest, lambda r, _: wash_plan_reply(cfg, meshes, r))
        server.announce()
        log.info("planner %s serving %s", instance, keys.planner_jobs(cfg.cell_id))
        try:
            stop_event.wait()
        finally:
            server.close()
            service.close()
    finally:
        session.close()
