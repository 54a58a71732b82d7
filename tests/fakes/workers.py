"""Scriptable worker doubles served over real Zenoh (tests only).

Each double serves the contract's keys with :class:`cellctl.workers._server.WorkerServer`;
tests change ``behaviour`` to make an op fail, hang or return something else.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from cellctl.bus import keys
from cellctl.bus.session import open_session
from cellctl.config import CellConfig
from cellctl.errors import RobotError
from cellctl.geometry.transforms import transform_from_xyz_rpy
from cellctl.messages import (
    ApproachReply,
    ApproachRequest,
    CaptureReply,
    CaptureRequest,
    ClassifyReply,
    ClassifyRequest,
    Intrinsics,
    MoveReply,
    MoveRequest,
    PlanJobQuery,
    PlanJobReply,
    PlanJobRequest,
    PlanLookupReply,
    PlanLookupRequest,
    PlannedViewpoint,
    PoseMsg,
    RobotState,
    RobotStateRequest,
    StopRequest,
    WashPlanRequest,
    WashReply,
    WashRequest,
)
from cellctl.workers._server import WorkerServer

CAM_POSE = PoseMsg.from_matrix(transform_from_xyz_rpy((0.5, 0.0, 1.2), (np.pi, 0.0, 0.0)))
INTRINSICS = Intrinsics(width=64, height=48, fx=60.0, fy=60.0, cx=32.0, cy=24.0)


@dataclass
class FakeIdentification:
    bin_type: str
    T_base_bin: Any


def fake_identify(image, intrinsics, T_base_cam, catalog):
    """Identifies every image as a 'case_study' bin 1 m in front of the base."""
    return FakeIdentification("case_study", transform_from_xyz_rpy((1.0, 0.0, 0.0), (0, 0, 0)))


def _png(value: int = 128) -> bytes:
    ok, buf = cv2.imencode(".png", np.full((48, 64, 3), value, np.uint8))
    assert ok
    return buf.tobytes()


@dataclass
class FakeCell:
    """Robot, camera, classifier and planner doubles on one client session."""

    cfg: CellConfig
    roles: tuple[str, ...] = ("robot", "camera", "classifier", "planner")
    n_viewpoints: int = 3
    plan_hit: bool = True
    dirty_viewpoints: set[int] = field(default_factory=set)
    move_delay_s: float = 0.0
    hang: set[str] = field(default_factory=set)  # ops that block forever
    fail: dict[str, str] = field(default_factory=dict)  # op -> reason
    delays: dict[str, float] = field(default_factory=dict)  # op -> seconds each call takes
    calls: list[str] = field(default_factory=list)
    stops: int = 0

    def __post_init__(self) -> None:
        self.session = open_session(self.cfg, "client")
        self.servers: dict[str, WorkerServer] = {}
        self._release = threading.Event()

    def _guard(self, op: str) -> None:
        self.calls.append(op)
        if op in self.delays:
            time.sleep(self.delays[op])
        if op in self.hang:
            self._release.wait(30)
        if op in self.fail:
            raise RobotError(self.fail[op])

    def start(self) -> FakeCell:
        c = self.cfg.cell_id
        for role in self.roles:
            self.servers[role] = WorkerServer(self.session, c, role, "fake" if role == "planner" else None)
        if "robot" in self.servers:
            r = self.servers["robot"]
            r.serve("approach", ApproachRequest, self._approach)
            r.serve("move", MoveRequest, self._move)
            r.serve(
                "state",
                RobotStateRequest,
                lambda q, p: RobotState(joints=[0.0] * 6, flange_pose=CAM_POSE, camera_pose=CAM_POSE),
            )
            r.serve("stop", StopRequest, self._stop)
            r.serve("wash", WashRequest, self._wash)
        if "camera" in self.servers:
            self.servers["camera"].serve("capture", CaptureRequest, self._capture)
        if "classifier" in self.servers:
            self.servers["classifier"].serve("classify", ClassifyRequest, self._classify)
        if "planner" in self.servers:
            p = self.servers["planner"]
            p.serve("lookup", PlanLookupRequest, self._lookup)
            p.serve("jobs", (PlanJobRequest, PlanJobQuery), self._submit, key=keys.planner_jobs(c))
            # the real wash planner, as the planner worker serves it (a plan is geometry, not a double)
            from cellctl.washing.service import MeshCache, wash_plan_reply

            meshes = MeshCache(self.cfg)
            p.serve("wash_plan", WashPlanRequest, lambda r, _: wash_plan_reply(self.cfg, meshes, r))
        for s in self.servers.values():
            s.announce()
        time.sleep(0.2)  # let the liveliness tokens reach the router
        return self

    def _approach(self, req: ApproachRequest, _: bytes | None) -> ApproachReply:
        self._guard("approach")
        return ApproachReply(
            joints=[0.0] * 6, flange_pose=CAM_POSE, camera_pose=CAM_POSE, observation_index=req.observation_index
        )

    def _move(self, req: MoveRequest, _: bytes | None) -> MoveReply:
        self._guard("move")
        time.sleep(self.move_delay_s)
        return MoveReply(joints=req.joints or [0.0] * 6, camera_pose=CAM_POSE)

    def _wash(self, req: WashRequest, _: bytes | None) -> WashReply:
        self._guard("wash")
        passes = sum(s.passes for s in req.sweeps)
        return WashReply(sweeps_run=len(req.sweeps), passes_run=passes, joints=req.sweeps[-1].joints[-1])

    def _stop(self, req: StopRequest, _: bytes | None) -> StopRequest:
        self.stops += 1
        self.calls.append("stop")
        return req

    def _capture(self, req: CaptureRequest, _: bytes | None) -> tuple[CaptureReply, bytes]:
        self._guard("capture")
        return CaptureReply(format="png", intrinsics=INTRINSICS, camera_pose=CAM_POSE), _png()

    def _classify(self, req: ClassifyRequest, image: bytes | None) -> ClassifyReply:
        self._guard("classify")
        n = sum(1 for c in self.calls if c == "classify") - 1
        dirty = n in self.dirty_viewpoints
        # a view sent with its reference is judged against it, as the real worker does when it aligns
        path = {"decided_by": "reference", "reference_reason": "aligned"} if req.reference is not None else {}
        return ClassifyReply(
            label="dirty" if dirty else "clean", p_dirty=0.9 if dirty else 0.1, model_id="fake", **path
        )

    def _lookup(self, req: PlanLookupRequest, _: bytes | None) -> PlanLookupReply:
        self._guard("lookup")
        if not self.plan_hit:
            return PlanLookupReply(hit=False, reason=f"no plan for bin type {req.bin_type!r}")
        vps = [
            PlannedViewpoint(index=i, camera_pose=CAM_POSE, joints=[0.1 * i] * 6, faces=[2 * i, 2 * i + 1])
            for i in range(self.n_viewpoints)
        ]
        return PlanLookupReply(hit=True, plan_id="plan-1", viewpoints=vps, coverage=0.9, mesh_faces=10)

    def _submit(self, req: PlanJobRequest | PlanJobQuery, _: bytes | None) -> PlanJobReply:
        self._guard("jobs")
        return PlanJobReply(job_id="job-1", state="queued")

    def kill(self, role: str) -> None:
        """Take one worker off the bus (its liveliness token goes away)."""
        self.servers.pop(role).close()

    def close(self) -> None:
        self._release.set()
        for s in self.servers.values():
            s.close()
        self.session.close()

    def __enter__(self) -> FakeCell:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
