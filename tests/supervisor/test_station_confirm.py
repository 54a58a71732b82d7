"""Confirming a certain-dirty view by a re-look (classifier.relook.confirm_dirty; whole-bin cycles by default)."""

from __future__ import annotations

from concurrent.futures import Future

import numpy as np
import pytest

from cellctl.messages import CaptureReply, ClassifyReply, MoveReply, PoseMsg, StationInfo, ViewpointResult
from cellctl.supervisor.context.scan import Scan
from cellctl.supervisor.steps.classifying import Classifying
from tests.fakes.workers import CAM_POSE, INTRINSICS, _png
from tests.supervisor._scripted import ScriptedRun, context


def _done(label: str, p: float, uncertain: bool = False) -> Future:
    f: Future = Future()
    f.set_result(ClassifyReply(label=label, p_dirty=p, uncertain=uncertain, model_id="m"))
    return f


def _ctx(cfg, whole: bool):
    cfg.planner.whole.enabled = whole
    where = {"station": 0, "surface": "external"} if whole else {}
    ctx = context(
        cfg,
        scan=Scan(viewpoints=[ViewpointResult(index=i, camera_pose=CAM_POSE, **where) for i in range(3)]),
    )
    if whole:
        ctx.stations.planned = [
            StationInfo(station=0, base_pose=PoseMsg.from_matrix(CAM_POSE.matrix(), "bin"), plans={"external": "p"})
        ]
        ctx.stations.station_order = [0]
    ctx.scan.classifications = {0: _done("clean", 0.05), 1: _done("dirty", 0.8), 2: _done("clean", 0.1)}
    return ctx


def _run(ctx, relook: ClassifyReply) -> ScriptedRun:
    script = {
        ("robot", "move"): lambda req: (MoveReply(joints=[0.0] * 6, camera_pose=req.camera_pose), None),
        ("camera", "capture"): (CaptureReply(format="png", intrinsics=INTRINSICS, camera_pose=CAM_POSE), _png()),
        ("classifier", "classify"): (relook, None),
    }
    return ScriptedRun(ctx, script)


@pytest.mark.parametrize(
    "relook, verdict",
    [
        (ClassifyReply(label="clean", p_dirty=0.08, model_id="m"), "clean"),  # a certain-clean re-look overrules
        (ClassifyReply(label="clean", p_dirty=0.45, uncertain=True, model_id="m"), "dirty"),  # an unsure one not
        (ClassifyReply(label="dirty", p_dirty=0.9, model_id="m"), "dirty"),
    ],
)
def test_a_whole_bin_cycle_re_looks_once_at_a_certain_dirty_view(cfg, relook, verdict) -> None:
    ctx = _ctx(cfg, whole=True)
    run = _run(ctx, relook)
    assert Classifying()(run) == "succeeded"
    again = [v for v in ctx.scan.viewpoints if v.relook_of is not None]
    assert [(v.index, v.relook_of, v.station, v.surface) for v in again][:1] == [(1, 1, 0, "external")]
    assert ctx.result.verdict == verdict


def test_a_single_station_cycle_keeps_a_certain_dirty_view_without_a_re_look(cfg) -> None:
    ctx = _ctx(cfg, whole=False)
    run = _run(ctx, ClassifyReply(label="clean", p_dirty=0.08, model_id="m"))
    assert Classifying()(run) == "succeeded"
    assert run.calls == [] and ctx.result.verdict == "dirty"
    cfg.classifier.relook.confirm_dirty = "on"  # on: single-station cycles confirm too
    ctx = _ctx(cfg, whole=False)
    run = _run(ctx, ClassifyReply(label="clean", p_dirty=0.08, model_id="m"))
    assert Classifying()(run) == "succeeded"
    assert ctx.result.verdict == "clean" and len(ctx.scan.viewpoints) == 4


def test_once_a_dirty_view_is_confirmed_no_further_one_is_re_looked(cfg) -> None:
    ctx = _ctx(cfg, whole=True)
    ctx.scan.classifications = {0: _done("dirty", 0.9), 1: _done("dirty", 0.8), 2: _done("dirty", 0.85)}
    run = _run(ctx, ClassifyReply(label="dirty", p_dirty=0.9, model_id="m"))
    assert Classifying()(run) == "succeeded"
    assert [v.relook_of for v in ctx.scan.viewpoints if v.relook_of is not None] == [1]  # the least sure, then stop
    assert ctx.result.verdict == "dirty"


def _scan_run(ctx, move) -> ScriptedRun:
    """A scripted scan: the robot's moves by ``move``, every capture a clean view."""
    script = {
        ("robot", "move"): move,
        ("camera", "capture"): (CaptureReply(format="png", intrinsics=INTRINSICS, camera_pose=CAM_POSE), _png()),
        ("classifier", "classify"): (ClassifyReply(label="clean", p_dirty=0.1, model_id="m"), None),
    }
    return ScriptedRun(ctx, script)


def test_a_whole_bin_scan_retries_refused_joints_by_the_camera_pose(cfg) -> None:
    from cellctl.errors import WorkerFailed
    from cellctl.messages import PlanLookupReply, PlannedViewpoint
    from cellctl.supervisor.steps.scanning import Scanning

    cfg.planner.whole.enabled = True
    ctx = context(cfg)
    ctx.stations.planned = [
        StationInfo(station=0, base_pose=PoseMsg.from_matrix(CAM_POSE.matrix(), "bin"), plans={"external": "p"})
    ]
    ctx.stations.station_order = [0]
    vps = [PlannedViewpoint(index=i, camera_pose=CAM_POSE, joints=[0.1 * i] * 6, faces=[i]) for i in range(2)]
    ctx.scan.plan = PlanLookupReply(hit=True, plan_id="p", viewpoints=vps, mesh_faces=10)

    def move(req):
        if req.joints == [0.1] * 6:
            raise WorkerFailed("target joints are in collision: wrist_2 vs bin", role="robot")
        return MoveReply(joints=[0.0] * 6, camera_pose=CAM_POSE), None

    run = _scan_run(ctx, move)
    assert Scanning()(run) == "succeeded"
    assert [v.error for v in ctx.scan.viewpoints] == [None, None]
    moves = [m for r, op, m in run.calls if (r, op) == ("robot", "move")]
    assert [m.joints is None for m in moves] == [False, False, True]  # viewpoint 1 again, by its camera pose
    assert any("reached by its camera pose" in t for _, t in run.events)


def test_in_a_whole_bin_cycle_an_uncertain_view_and_its_re_look_are_fused_by_their_mean(cfg) -> None:
    ctx = _ctx(cfg, whole=True)
    # the demo's case: uncertain dirty at p 0.78, a certain-clean re-look at p 0.002 (nearest-the-mean: a tie)
    ctx.scan.classifications = {
        0: _done("clean", 0.05),
        1: _done("dirty", 0.78, uncertain=True),
        2: _done("clean", 0.1),
    }
    run = _run(ctx, ClassifyReply(label="clean", p_dirty=0.002, model_id="m"))
    assert Classifying()(run) == "succeeded"
    assert ctx.result.verdict == "clean"
    ctx = _ctx(cfg, whole=True)
    ctx.scan.classifications = {0: _done("clean", 0.05), 1: _done("dirty", 0.9, uncertain=True), 2: _done("clean", 0.1)}
    run = _run(ctx, ClassifyReply(label="clean", p_dirty=0.45, uncertain=True, model_id="m"))
    assert Classifying()(run) == "succeeded"
    assert ctx.result.verdict == "dirty"  # mean logit 1.0 above the threshold estimate 0


@pytest.mark.parametrize("first", ["dirty", "uncertain"])
def test_a_refused_re_look_pose_is_followed_by_the_next_one(cfg, first) -> None:
    """Near a rim the first swing can touch the bin: the next re-look pose is tried, at no budget cost."""
    from cellctl.errors import WorkerFailed

    ctx = _ctx(cfg, whole=True)
    if first == "uncertain":
        ctx.scan.classifications = {0: _done("clean", 0.05), 1: _done("dirty", 0.6, True), 2: _done("clean", 0.1)}
    cfg.classifier.relook.max_views = 1
    refused = 0

    def move(req):
        nonlocal refused
        if refused < 2:
            refused += 1
            raise WorkerFailed("camera pose is unreachable without collision: all 8 IK solutions collide", role="robot")
        return MoveReply(joints=[0.0] * 6, camera_pose=req.camera_pose), None

    run = _run(ctx, ClassifyReply(label="clean", p_dirty=0.02, model_id="m"))
    run.script[("robot", "move")] = move
    assert Classifying()(run) == "succeeded"
    poses = [m.camera_pose.matrix() for r, op, m in run.calls if (r, op) == ("robot", "move")]
    assert len(poses) == 3 and not np.allclose(poses[0], poses[1]) and not np.allclose(poses[1], poses[2])
    relooks = [v for v in ctx.scan.viewpoints if v.relook_of == 1]
    assert [v.error is None for v in relooks] == [False, False, True]
    assert ctx.result.verdict == "clean"  # the third pose's certain-clean view overrules (or outweighs) the first


def test_a_view_whose_every_re_look_pose_is_refused_keeps_its_label(cfg) -> None:
    from cellctl.errors import WorkerFailed

    ctx = _ctx(cfg, whole=True)

    def move(req):
        raise WorkerFailed("camera pose is unreachable without collision", role="robot")

    run = _run(ctx, ClassifyReply(label="clean", p_dirty=0.02, model_id="m"))
    run.script[("robot", "move")] = move
    assert Classifying()(run) == "succeeded"
    assert len([1 for r, op, _ in run.calls if (r, op) == ("robot", "move")]) == 4  # the four swings, then stop
    assert ctx.result.verdict == "dirty"


def test_a_whole_bin_scan_tries_nearby_views_when_the_camera_pose_is_refused_too(cfg) -> None:
    """Joints and camera pose refused (the rim on every IK solution after a tolerated pose error):
    the view backed off / rolled is tried, and the first one the arm reaches is the view."""
    from cellctl.errors import WorkerFailed
    from cellctl.messages import PlanLookupReply, PlannedViewpoint
    from cellctl.planning.adjust import nearby_views
    from cellctl.supervisor.steps.scanning import Scanning

    cfg.planner.whole.enabled = True
    ctx = context(cfg)
    ctx.stations.planned = [
        StationInfo(station=0, base_pose=PoseMsg.from_matrix(CAM_POSE.matrix(), "bin"), plans={"internal": "p"})
    ]
    ctx.stations.station_order = [0]
    vps = [PlannedViewpoint(index=0, camera_pose=CAM_POSE, joints=[0.1] * 6, faces=[0])]
    ctx.scan.plan = PlanLookupReply(hit=True, plan_id="p", viewpoints=vps, mesh_faces=10)
    reachable = nearby_views(CAM_POSE.matrix())[1]  # 20 mm further back

    def move(req):
        if req.joints is not None or not np.allclose(req.camera_pose.matrix(), reachable, atol=1e-6):
            raise WorkerFailed("target joints are in collision: wrist_3 vs bin", role="robot")
        return MoveReply(joints=[0.0] * 6, camera_pose=req.camera_pose), None

    run = _scan_run(ctx, move)
    assert Scanning()(run) == "succeeded"
    assert [v.error for v in ctx.scan.viewpoints] == [None]
    moves = [m for r, op, m in run.calls if (r, op) == ("robot", "move")]
    assert len(moves) == 4  # joints, camera pose, 10 mm back, 20 mm back (reached: no further try)
    assert any("20 mm further back" in t for _, t in run.events)
