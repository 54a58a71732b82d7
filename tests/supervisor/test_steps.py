"""Each cycle step on its own: a scripted StepRun answers the worker calls (no Zenoh, no machine)."""

from __future__ import annotations

from concurrent.futures import Future

import numpy as np
import pytest

from cellctl.errors import ClassifierError, IdentificationError, PlanCacheError, WorkerFailed
from cellctl.messages import (
    ApproachReply,
    CaptureReply,
    ClassifyReply,
    CycleOutcome,
    MoveReply,
    PlanJobReply,
    PlanLookupReply,
    PlannedViewpoint,
    StartParams,
    ViewpointResult,
)
from cellctl.supervisor.context import BLACKBOARD, INITIAL_CONTEXT, Cancelled
from cellctl.supervisor.context.identity import Identity
from cellctl.supervisor.context.scan import Scan
from cellctl.supervisor.steps import STEPS
from cellctl.supervisor.steps.approaching import Approaching
from cellctl.supervisor.steps.checking_cache import CheckingCache
from cellctl.supervisor.steps.classifying import Classifying
from cellctl.supervisor.steps.identifying import Identifying
from cellctl.supervisor.steps.replanning import Replanning
from cellctl.supervisor.steps.reporting import Reporting
from cellctl.supervisor.steps.scanning import Scanning
from tests.fakes.workers import CAM_POSE, INTRINSICS, _png, fake_identify
from tests.supervisor._scripted import ListRecorder, ScriptedRun, context

APPROACH = ApproachReply(joints=[0.0] * 6, flange_pose=CAM_POSE, camera_pose=CAM_POSE)
CAPTURE = (CaptureReply(format="png", intrinsics=INTRINSICS, camera_pose=CAM_POSE), _png())
T_BIN = np.eye(4)


def _plan(n: int = 3) -> PlanLookupReply:
    vps = [
        PlannedViewpoint(index=i, camera_pose=CAM_POSE, joints=[0.1 * i] * 6, faces=[2 * i, 2 * i + 1])
        for i in range(n)
    ]
    return PlanLookupReply(hit=True, plan_id="plan-1", viewpoints=vps, mesh_faces=10)


def _done(reply: ClassifyReply) -> Future:
    f: Future = Future()
    f.set_result(reply)
    return f


def test_every_step_declares_fields_of_the_context() -> None:
    fields = BLACKBOARD
    assert set(INITIAL_CONTEXT) <= fields
    for name, step in STEPS.items():
        assert set(step.READS) <= fields, name
        assert set(step.WRITES) <= fields, name
        assert set(step.CONSULTS) <= fields, name


def test_approaching_parks_first_then_only_moves_the_arm(cfg) -> None:
    ctx = context(cfg)
    run = ScriptedRun(ctx, {("robot", "approach"): (APPROACH, None)})
    assert Approaching()(run) == "succeeded"
    assert ctx.identity.approach == APPROACH and run.calls[0][2].park is True
    ctx.identity.observation_index = 1
    Approaching()(run)
    assert run.calls[1][2].park is False and run.calls[1][2].observation_index == 1


def test_identifying_sets_the_bin_and_records_the_image(cfg) -> None:
    rec = ListRecorder()
    ctx = context(cfg, log=rec, identity=Identity(approach=APPROACH), identify=fake_identify)
    run = ScriptedRun(ctx, {("camera", "capture"): CAPTURE})
    assert Identifying()(run) == "succeeded"
    assert (
        ctx.identity.bin_type == "case_study"
        and ctx.identity.T_base_bin is not None
        and ctx.identity.T_base_bin.shape == (4, 4)
    )
    assert ("/camera/image", "foxglove.CompressedImage") in rec.records
    assert ("/bin/pose", "foxglove.PoseInFrame") in rec.records


def test_identifying_retries_from_the_next_pose_then_fails(cfg) -> None:
    def blind(*a):
        raise IdentificationError("no board in view")

    cfg.supervisor.identify_attempts = 2
    ctx = context(cfg, identity=Identity(approach=APPROACH), identify=blind)
    run = ScriptedRun(ctx, {("camera", "capture"): CAPTURE})
    assert Identifying()(run) == "retry"
    assert ctx.identity.observation_index == 1 and ctx.identity.identify_attempts == 1
    with pytest.raises(IdentificationError, match="not identified after 2 observation poses: no board in view"):
        Identifying()(run)


def test_checking_cache_hit_miss_and_a_hit_without_viewpoints(cfg) -> None:
    ctx = context(
        cfg, params=StartParams(surface="internal"), identity=Identity(bin_type="case_study", T_base_bin=T_BIN)
    )
    run = ScriptedRun(ctx, {("planner", "lookup"): (_plan(), None)})
    assert CheckingCache()(run) == "hit"
    assert ctx.scan.plan is not None and ctx.scan.plan.plan_id == "plan-1"
    assert run.calls[0][2].surface == "internal"  # the Start param, not the config default
    run.script[("planner", "lookup")] = (PlanLookupReply(hit=False, reason="pose out of tolerance"), None)
    assert CheckingCache()(run) == "miss"
    assert ("info", "no usable plan: pose out of tolerance") in run.events
    run.script[("planner", "lookup")] = (PlanLookupReply(hit=True, plan_id="p"), None)
    with pytest.raises(PlanCacheError, match="hit on plan 'p' but no viewpoints"):
        CheckingCache()(run)


def test_replanning_submits_and_ends_with_replan_required(cfg) -> None:
    ctx = context(cfg, identity=Identity(bin_type="case_study", T_base_bin=T_BIN, approach=APPROACH))
    run = ScriptedRun(ctx, {("planner", "jobs"): (PlanJobReply(job_id="job-7"), None)})
    assert Replanning()(run) == "submitted"
    assert ctx.scan.planner_job_id == "job-7" and ctx.result.outcome == CycleOutcome.replan_required
    assert run.calls[0][2].q_start == [0.0] * 6  # the tour starts where the arm is


def test_scanning_visits_every_viewpoint_and_a_refused_one_costs_only_coverage(cfg) -> None:
    def move(req):
        if req.joints == [0.1] * 6:
            raise WorkerFailed("viewpoint in collision", role="robot")
        return MoveReply(joints=req.joints, camera_pose=CAM_POSE), None

    ctx = context(cfg, scan=Scan(plan=_plan(3)))
    run = ScriptedRun(
        ctx,
        {
            ("robot", "move"): move,
            ("camera", "capture"): CAPTURE,
            ("classifier", "classify"): (ClassifyReply(label="clean", p_dirty=0.1, model_id="m"), None),
        },
    )
    try:
        assert Scanning()(run) == "succeeded"
        assert [v.index for v in ctx.scan.viewpoints] == [0, 1, 2]
        assert ctx.scan.viewpoints[1].error == "viewpoint in collision" and ctx.scan.next_viewpoint == 3
        assert sorted(ctx.scan.classifications) == [0, 2]
        assert ctx.scan.classifications[0].result(timeout=5).label == "clean"
    finally:
        ctx.shutdown()


def test_a_classification_outlives_a_hold_of_scanning_but_not_the_cycle(cfg) -> None:
    ctx = context(cfg)
    run = ScriptedRun(ctx, {})
    background = run.detached("classify_background")
    run.cancelled.set()  # Hold: the scanning activation is cancelled
    background.checkpoint()  # ... its background work goes on
    with pytest.raises(Cancelled):
        run.checkpoint()
    ctx.shutdown()  # the cycle ended
    with pytest.raises(Cancelled):
        background.checkpoint()


def test_scanning_fails_when_no_viewpoint_was_reached(cfg) -> None:
    def refuse(req):
        raise WorkerFailed("unreachable", role="robot")

    ctx = context(cfg, scan=Scan(plan=_plan(2)))
    with pytest.raises(WorkerFailed, match="reached none of the 2 planned viewpoints"):
        Scanning()(ScriptedRun(ctx, {("robot", "move"): refuse}))


def test_classifying_decides_dirty_if_any_viewpoint_is_dirty(cfg) -> None:
    ctx = context(cfg, scan=Scan(viewpoints=[ViewpointResult(index=0), ViewpointResult(index=1)]))
    ctx.scan.classifications = {
        0: _done(ClassifyReply(label="clean", p_dirty=0.1, model_id="m")),
        1: _done(ClassifyReply(label="dirty", p_dirty=0.8, uncertain=True, model_id="m")),
    }
    assert Classifying()(ScriptedRun(ctx, {})) == "succeeded"
    assert ctx.result.verdict == "dirty" and [v.label for v in ctx.scan.viewpoints] == ["clean", "dirty"]
    assert ctx.scan.classifications == {}


def test_classifying_without_any_label_fails(cfg) -> None:
    ctx = context(cfg, scan=Scan(viewpoints=[ViewpointResult(index=0, error="unreachable")]))
    with pytest.raises(ClassifierError, match="no viewpoint was classified"):
        Classifying()(ScriptedRun(ctx, {}))


def test_reporting_maps_dirt_and_coverage_and_completes(cfg) -> None:
    vps = [
        ViewpointResult(index=0, label="clean"),
        ViewpointResult(index=1, label="dirty"),
        ViewpointResult(index=2, error="x"),
    ]
    ctx = context(cfg, scan=Scan(plan=_plan(3), viewpoints=vps))
    assert Reporting()(ScriptedRun(ctx, {})) == "succeeded"
    assert ctx.result.dirt_map == {"faces_total": 10, "seen_dirty": [2, 3], "seen_clean": [0, 1], "unseen_count": 6}
    assert ctx.result.coverage == pytest.approx(0.4)
    assert ctx.result.outcome == CycleOutcome.completed


def test_the_cabin_past_the_bin_is_filled_for_the_classifier_and_the_bin_is_not(cfg) -> None:
    """An internal view that also sees the lit cabin past the rim: the off-bin pixels get the bin's median colour."""
    import cv2

    from cellctl.geometry.catalog import load_catalog
    from cellctl.geometry.transforms import transform_from_xyz_rpy
    from cellctl.messages import Intrinsics
    from cellctl.supervisor.steps.scanning import cabin_pixels, mask_cabin

    mesh = load_catalog(cfg.path(cfg.catalog)).load_mesh("case_study")
    intr = Intrinsics(width=320, height=240, fx=250.0, fy=250.0, cx=160.0, cy=120.0)
    T_base_bin = np.eye(4)
    # 1.5 m above the rim, looking straight down: the bin in the middle, the cabin floor around it
    T_base_cam = transform_from_xyz_rpy((0.0, 0.0, 1.5), (np.pi, 0.0, 0.0))
    off = cabin_pixels(mesh, T_base_bin, T_base_cam, intr, scale=1.0)
    assert off[0, 0] and off[-1, -1] and not off[120, 160]  # corners past the bin, centre on it
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
    img[off] = 250  # bright cabin
    out = cv2.imdecode(
        np.frombuffer(mask_cabin(cv2.imencode(".png", img)[1].tobytes(), mesh, T_base_bin, T_base_cam, intr), np.uint8),
        cv2.IMREAD_COLOR,
    )
    on = ~cv2.resize(
        cabin_pixels(mesh, T_base_bin, T_base_cam, intr).astype(np.uint8), (320, 240), interpolation=cv2.INTER_NEAREST
    ).astype(bool)
    assert np.array_equal(out[on], img[on])  # the bin as captured
    assert np.allclose(out[~on], np.median(img[on], axis=0), atol=1)  # the cabin: the bin's median colour
    # a camera inside the cavity (faces reach behind it: clipped, not dropped) sees only bin: unchanged
    inside = transform_from_xyz_rpy((0.0, 0.0, -0.1), (np.pi, 0.0, 0.0))
    png = cv2.imencode(".png", img)[1].tobytes()
    assert not cabin_pixels(mesh, T_base_bin, inside, intr).any()
    assert mask_cabin(png, mesh, T_base_bin, inside, intr) is png


def test_only_the_configured_surfaces_get_the_cabin_mask(cfg) -> None:
    import cv2

    from cellctl.geometry.catalog import load_catalog
    from cellctl.geometry.transforms import transform_from_xyz_rpy
    from cellctl.supervisor.steps.board_mask import mask_board
    from cellctl.supervisor.steps.scanning import classifier_input

    cat = load_catalog(cfg.path(cfg.catalog))
    T_cam = transform_from_xyz_rpy((0.0, 0.0, 1.5), (np.pi, 0.0, 0.0))
    png = cv2.imencode(".png", np.random.default_rng(1).integers(0, 255, (48, 64, 3), dtype=np.uint8))[1].tobytes()
    board = mask_board(png, cat.get("case_study"), np.eye(4), T_cam, INTRINSICS)  # the board mask, always
    for surface, masked in (("internal", True), ("external", False)):
        ctx = context(cfg, catalog=cat, identity=Identity(bin_type="case_study", T_base_bin=np.eye(4)))
        ctx.params = ctx.params.model_copy(update={"surface": surface})
        image, fmt = classifier_input(ScriptedRun(ctx, {}), png, "png", T_cam, INTRINSICS)
        assert (image != board) == masked and fmt == "png", surface


def test_the_masks_decode_under_the_cells_pixel_budget(cfg) -> None:
    """The board and cabin masks decode what the classifier will, under ``camera.max_image_pixels``: a
    budget below the image leaves it undecoded (the classifier refuses it), one that holds it masks it.
    (They used the default budget: a camera above 16.8 Mpx with a raised budget went unmasked.)"""
    import cv2

    from cellctl.geometry.camera import D435_COLOR
    from cellctl.geometry.catalog import load_catalog
    from cellctl.sim import scene
    from cellctl.supervisor.steps.scanning import classifier_input

    cat = load_catalog(cfg.path(cfg.catalog))
    T_cam = scene.observation_T_bin_cam(cat.get("case_study"), 0)  # facing the board, the cabin around the bin
    intr = D435_COLOR.scaled(0.2).intrinsics()  # 256 x 144
    rgb = np.random.default_rng(2).integers(0, 255, (intr.height, intr.width, 3), dtype=np.uint8)
    png = cv2.imencode(".png", rgb)[1].tobytes()
    n = intr.width * intr.height
    for budget, masked in ((n - 1, False), (n, True)):
        cfg.camera.max_image_pixels = budget
        for surface in ("external", "internal"):  # the board mask alone; board and cabin masks
            ctx = context(cfg, catalog=cat, identity=Identity(bin_type="case_study", T_base_bin=np.eye(4)))
            ctx.params = ctx.params.model_copy(update={"surface": surface})
            image, _ = classifier_input(ScriptedRun(ctx, {}), png, "png", T_cam, intr)
            assert (image is not png) == masked, (budget, surface)
