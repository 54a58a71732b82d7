"""The cycle steps with the detector's replies: re-look at an uncertain view, heat maps recorded,
heat maps projected with the reached pose (scripted workers, no Zenoh)."""

from __future__ import annotations

from concurrent.futures import Future

import numpy as np
import pytest

from cellctl.bus import topics
from cellctl.classify.heatmap import encode_heat
from cellctl.messages import (
    CaptureReply,
    ClassifyReply,
    MoveReply,
    PlanLookupReply,
    PlannedViewpoint,
    PoseMsg,
    ViewpointResult,
)
from cellctl.supervisor.context.scan import Scan
from cellctl.supervisor.steps.classifying import Classifying
from cellctl.supervisor.steps.reporting import view_evidence
from tests.fakes.workers import CAM_POSE, INTRINSICS, _png
from tests.supervisor._scripted import ListRecorder, ScriptedRun, context

HOT = np.zeros((16, 16))
HOT[4:8, 4:8] = 0.9


def _reply(label: str, p: float, uncertain: bool = False) -> ClassifyReply:
    return ClassifyReply(
        label=label,
        p_dirty=p,
        uncertain=uncertain,
        model_id="external-detect-x",
        p_supervised=p,
        anomaly_z=1.0,
        heatmap=encode_heat(HOT),
        heat_grid=16,
    )


def _done(r: ClassifyReply) -> Future:
    f: Future = Future()
    f.set_result(r)
    return f


@pytest.fixture
def cfg():
    from cellctl.config import load_config

    return load_config()


def _ctx(cfg, max_views: int):
    cfg = cfg.model_copy(
        update={
            "classifier": cfg.classifier.model_copy(
                update={"relook": cfg.classifier.relook.model_copy(update={"max_views": max_views})}
            )
        }
    )
    ctx = context(
        cfg,
        log=ListRecorder(),
        scan=Scan(
            viewpoints=[ViewpointResult(index=0, camera_pose=CAM_POSE), ViewpointResult(index=1, camera_pose=CAM_POSE)]
        ),
    )
    ctx.scan.classifications = {0: _done(_reply("clean", 0.05)), 1: _done(_reply("dirty", 0.55, uncertain=True))}
    return ctx


def test_an_uncertain_view_is_relooked_from_a_nearby_pose_and_heat_maps_are_recorded(cfg) -> None:
    ctx = _ctx(cfg, 4)
    script = {
        ("robot", "move"): lambda req: (MoveReply(joints=[0.0] * 6, camera_pose=req.camera_pose), None),
        ("camera", "capture"): (CaptureReply(format="png", intrinsics=INTRINSICS, camera_pose=CAM_POSE), _png()),
        ("classifier", "classify"): (_reply("dirty", 0.97), None),
    }
    run = ScriptedRun(ctx, script)
    assert Classifying()(run) == "succeeded"
    assert len(ctx.scan.viewpoints) == 3
    again = ctx.scan.viewpoints[2]
    assert again.relook_of == 1 and again.index == 1 and again.label == "dirty" and not again.uncertain
    moves = [m for r, op, m in run.calls if (r, op) == ("robot", "move")]
    assert len(moves) == 1 and moves[0].camera_pose is not None and moves[0].joints is None
    d = np.linalg.norm(moves[0].camera_pose.matrix()[:3, 3] - CAM_POSE.matrix()[:3, 3])
    assert 0.01 < d < 0.2  # nearby, not the same pose
    assert [t for t, _ in ctx.log.records].count(topics.HEATMAP) == 3
    assert ctx.result.verdict == "dirty" and any("1 re-looks" in text for _, text in run.events)


def test_relook_off_asks_the_robot_nothing(cfg) -> None:
    ctx = _ctx(cfg, 0)
    run = ScriptedRun(ctx, {})
    assert Classifying()(run) == "succeeded"
    assert run.calls == [] and len(ctx.scan.viewpoints) == 2 and ctx.scan.viewpoints[1].uncertain


def test_view_evidence_uses_the_reached_pose_in_the_bin_frame() -> None:
    plan = PlanLookupReply(
        hit=True,
        plan_id="p",
        mesh_faces=10,
        viewpoints=[PlannedViewpoint(index=0, camera_pose=CAM_POSE, joints=[0.0] * 6, faces=[1, 2])],
    )
    T_base_bin = np.eye(4)
    T_base_bin[:3, 3] = (0.3, 0.1, 0.0)
    reached = PoseMsg.from_matrix(CAM_POSE.matrix() @ np.diag([1.0, 1.0, 1.0, 1.0]))
    vs = [
        ViewpointResult(
            index=0, camera_pose=reached, label="dirty", p_dirty=0.9, heatmap=encode_heat(HOT), heat_grid=16
        ),
        ViewpointResult(index=0, label="clean", p_dirty=0.1),  # a whole-image reply: no heat map
        ViewpointResult(index=0, error="refused"),
    ]
    ev = view_evidence(plan, vs, T_base_bin)
    assert len(ev) == 2
    assert np.allclose(ev[0].T_bin_cam, np.linalg.inv(T_base_bin) @ reached.matrix())
    assert ev[0].heat is not None and abs(ev[0].heat[5, 5] - 0.9) < 0.01 and ev[0].faces.tolist() == [1, 2]
    assert ev[1].heat is None and ev[1].p_dirty == 0.1
