"""wash_check → washing → verifying (Start mode wash_and_verify) on the case-study bin: the real
wash planner (the planner worker's service, called in-process), scripted robot/camera/classifier
replies (no Zenoh)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cellctl.errors import RobotError, WorkerFailed
from cellctl.geometry.catalog import load_catalog
from cellctl.geometry.transforms import invert
from cellctl.messages import (
    CaptureReply,
    ClassifyReply,
    MoveReply,
    PlanLookupReply,
    PlannedViewpoint,
    RobotState,
    StartParams,
    WashReply,
    WashRound,
)
from cellctl.sim.ground_truth import PowderField
from cellctl.sim.scene import HOME_JOINTS, nominal_T_bin_base
from cellctl.supervisor.context.identity import Identity
from cellctl.supervisor.context.result import Result
from cellctl.supervisor.context.scan import Scan
from cellctl.supervisor.context.stations import Stations
from cellctl.supervisor.steps.verifying import Verifying, imaged_faces, merge_dirt_maps
from cellctl.supervisor.steps.washing import WashCheck, Washing, WashStation
from cellctl.surface import EXTERNAL
from cellctl.washing.service import MeshCache, wash_plan_reply
from tests.fakes.workers import CAM_POSE, INTRINSICS, _png
from tests.supervisor._scripted import ListRecorder, ScriptedRun, context

WASH = StartParams(mode="wash_and_verify")
STATE = RobotState(joints=HOME_JOINTS.tolist(), flange_pose=CAM_POSE, camera_pose=CAM_POSE)


class DiskRecorder(ListRecorder):
    def __init__(self, path: Path) -> None:
        super().__init__()
        self.path = path


def _dirty(mesh, centre, normal) -> np.ndarray:
    f = PowderField(np.array([centre], float), np.array([0.04]), np.array([EXTERNAL], np.uint8), np.array([normal]), 7)
    return f.dirty_faces(mesh)


@pytest.fixture
def case(cfg):
    cat = load_catalog(cfg.path(cfg.catalog), cfg.root)
    mesh = cat.load_mesh("case_study")
    T_base_bin = invert(nominal_T_bin_base(cat.get("case_study"), mesh))
    return cat, mesh, T_base_bin


def _ctx(cfg, case, dirty: np.ndarray | None, min_seen: float = 0.0, **kw):
    """A scripted cycle's blackboard; its views see a few faces, so ``wash.min_seen_fraction`` is
    ``min_seen`` (0: the coverage bound is tested on its own)."""
    cat, mesh, T = case
    cfg = cfg.model_copy(update={"wash": cfg.wash.model_copy(update={"min_seen_fraction": min_seen})})
    dm = None if dirty is None else {"seen_dirty": np.flatnonzero(dirty).tolist(), "seen_clean": []}
    # the inspection plan: one viewpoint sees the dirty faces, one sees faces far from them
    far = np.flatnonzero(~dirty)[:5].tolist() if dirty is not None else [0]
    near = np.flatnonzero(dirty).tolist() if dirty is not None else [1]
    vps = [
        PlannedViewpoint(index=0, camera_pose=CAM_POSE, joints=[0.1] * 6, faces=near),
        PlannedViewpoint(index=1, camera_pose=CAM_POSE, joints=[0.2] * 6, faces=far),
    ]
    plan = PlanLookupReply(hit=True, plan_id="p", viewpoints=vps, mesh_faces=mesh.n_faces)
    return context(
        cfg,
        params=WASH,
        catalog=cat,
        identity=Identity(bin_type="case_study", T_base_bin=T),
        result=Result(dirt_map=dm),
        scan=Scan(plan=plan),
        **kw,
    )


def _script(cfg, refuse_second: bool = False, label: str = "clean") -> dict:
    calls = {"n": 0}
    meshes = MeshCache(cfg)

    def wash(req):
        calls["n"] += 1
        if refuse_second and calls["n"] == 2:
            raise WorkerFailed("wash sweep 0 (of 1, round 1) is in collision", role="robot")
        return WashReply(sweeps_run=1, passes_run=req.sweeps[0].passes, joints=req.sweeps[0].joints[-1]), None

    return {
        ("robot", "state"): (STATE, None),
        ("planner", "wash_plan"): lambda req: (wash_plan_reply(cfg, meshes, req), None),
        ("robot", "wash"): wash,
        ("robot", "move"): (MoveReply(joints=[0.0] * 6, camera_pose=CAM_POSE), None),
        ("camera", "capture"): (CaptureReply(format="png", intrinsics=INTRINSICS, camera_pose=CAM_POSE), _png()),
        ("classifier", "classify"): (
            ClassifyReply(label=label, p_dirty=0.1 if label == "clean" else 0.9, model_id="m"),
            None,
        ),
    }


def test_other_modes_pass_wash_check_untouched(cfg, case) -> None:
    ctx = _ctx(cfg, case, _dirty(case[1], (0.2, -0.37, -0.15), (0, -1.0, 0)))
    ctx.mode = "evaluate"
    run = ScriptedRun(ctx, {})
    assert WashCheck()(run) == "done" and run.calls == [] and ctx.wash.result is None


def test_a_dirty_spot_is_washed_re_inspected_and_ends_clean_with_three_pictures(cfg, case, tmp_path) -> None:
    _, mesh, _ = case
    dirty = _dirty(mesh, (0.2, -0.37, -0.15), (0, -1.0, 0))
    log = DiskRecorder(tmp_path / "c-1.mcap")
    ctx = _ctx(cfg, case, dirty, log=log)
    run = ScriptedRun(ctx, _script(cfg, refuse_second=True))
    assert WashCheck()(run) == "wash"
    plan = ctx.wash.plan
    assert plan.sweeps and not plan.unwashable and len(plan.dirty) == dirty.sum() and plan.reason is None
    assert ctx.wash.queue == [None] and WashStation()(run) == "wash"  # single-station: no parking
    assert Washing()(run) == "succeeded"
    washes = [m for r, o, m in run.calls if o == "wash"]
    assert len(washes) == len(plan.sweeps)  # one request per sweep: a Hold resumes at the next
    assert [len(w.sweeps) for w in washes] == [1] * len(washes)
    assert washes[0].sweeps[0].joints == plan.sweeps[0].joints and washes[0].sweeps[0].passes == 2
    assert ctx.wash.run["sweeps_run"] == len(plan.sweeps) - 1 and len(ctx.wash.run["refused"]) == 1
    assert WashStation()(run) == "verify" and ctx.wash.verify_queue == [None]
    assert Verifying()(run) == "succeeded"
    moves = [m for r, o, m in run.calls if o == "move"]
    assert [list(m.joints) for m in moves] == [[0.1] * 6]  # only the viewpoint that sees the washed faces
    assert [v.wash_round for v in ctx.wash.views] == [1] and ctx.scan.viewpoints == []
    (rec,) = ctx.wash.rounds
    assert rec.dirty_faces_before == dirty.sum() and rec.dirty_faces_after == 0
    assert rec.sweeps_run == len(plan.sweeps) - 1 and rec.sweeps_refused and rec.reinspected_views == 1
    assert rec.pictures == ["r1_before.png", "r1_path.png", "r1_after.png"]
    for p in rec.pictures:
        assert (tmp_path / "c-1.wash" / p).stat().st_size > 10_000
    assert ("/wash/plan", "cellctl.WashPlan") in log.records and ("/wash/round", "cellctl.WashRound") in log.records
    assert WashCheck()(run) == "done"
    assert ctx.result.verdict == "clean" and ctx.wash.result.verdict == "clean" and len(ctx.wash.result.rounds) == 1
    assert ctx.wash.result.remaining_faces == []


def test_dirt_no_nozzle_pose_reaches_ends_dirty_as_unwashable_without_motion(cfg, case) -> None:
    dirty = _dirty(case[1], (0.0, 0.37, -0.5), (0, 1.0, 0))  # far outside wall, seen from the board side
    ctx = _ctx(cfg, case, dirty)
    run = ScriptedRun(ctx, _script(cfg))
    assert WashCheck()(run) == "done"
    assert [o for _, o, _ in run.calls] == ["state", "wash_plan"]  # no wash, no move
    assert ctx.result.verdict == "dirty" and ctx.wash.result.verdict == "dirty"
    assert ctx.wash.result.reason.startswith("unwashable: no nozzle pose reaches any dirty region")
    assert ctx.wash.result.unwashable and ctx.wash.result.remaining_faces == np.flatnonzero(dirty).tolist()


def test_no_dirt_map_is_a_reason_and_no_motion(cfg, case) -> None:
    ctx = _ctx(cfg, case, None)
    run = ScriptedRun(ctx, _script(cfg))
    assert WashCheck()(run) == "done" and run.calls == []
    assert ctx.wash.result.verdict is None and "no dirt map" in ctx.wash.result.reason


def test_dirt_left_after_the_last_round_ends_dirty(cfg, case) -> None:
    dirty = _dirty(case[1], (0.2, -0.37, -0.15), (0, -1.0, 0))
    ctx = _ctx(cfg, case, dirty)
    ctx.wash.rounds = [
        WashRound(
            round=k + 1,
            dirty_faces_before=1,
            dirty_m2_before=0.0,
            sweeps_planned=1,
            sweeps_run=1,
            passes_run=2,
            washed_m2=0.0,
            covered_m2=0.0,
        )  # fmt: skip
        for k in range(cfg.wash.max_rounds)
    ]
    run = ScriptedRun(ctx, _script(cfg))
    assert WashCheck()(run) == "done" and run.calls == []
    assert (
        ctx.result.verdict == "dirty"
        and "after 3 wash round(s)" in ctx.wash.result.reason
        and len(ctx.wash.result.rounds) == 3
    )


def test_a_hold_during_a_sweep_is_not_a_refusal_and_resumes_there(cfg, case) -> None:
    from cellctl.supervisor.context import Cancelled

    dirty = _dirty(case[1], (0.2, -0.37, -0.15), (0, -1.0, 0))
    ctx = _ctx(cfg, case, dirty)
    script = _script(cfg)
    run = ScriptedRun(ctx, script)
    assert WashCheck()(run) == "wash"

    def held(req):
        run.cancelled.set()  # the supervisor cancels the step, then stops the robot: the sweep fails
        raise WorkerFailed(str(RobotError("motion stopped (hold)")), role="robot")

    script[("robot", "wash")] = held
    with pytest.raises(Cancelled):
        Washing()(run)
    assert ctx.wash.next_sweep == 0 and ctx.wash.run["refused"] == []
    resumed = ScriptedRun(ctx, _script(cfg))
    assert Washing()(resumed) == "succeeded"
    assert ctx.wash.run["sweeps_run"] == len(ctx.wash.plan.sweeps)


def test_merging_keeps_unseen_faces_and_replaces_seen_ones(case) -> None:
    _, mesh, _ = case
    old = {"seen_dirty": [1, 2, 3], "seen_clean": [4]}
    new = {"seen_dirty": [3], "seen_clean": [1, 5]}
    from cellctl.washing.targets import dirty_from_map

    merged = merge_dirt_maps(old, new, mesh)
    dirty, source = dirty_from_map(merged, mesh.n_faces, 0.5)
    assert source == "face_p" and np.flatnonzero(dirty).tolist() == [2, 3]
    assert sorted(merged["seen_clean"]) == [1, 4, 5]


def _whole_ctx(cfg, case, dirty_a, dirty_b):
    """A whole-bin cycle at its end: station 0 (the nominal park) and station 1 (the far side, the
    bin turned half round), the base standing at station 1; each station's external plan has one
    viewpoint that sees its own dirty spot."""
    from cellctl.geometry.transforms import transform_from_xyz_rpy
    from cellctl.messages import PoseMsg, StationInfo

    cat, mesh, T_a = case
    whole = cfg.planner.whole.model_copy(update={"enabled": True})
    wash = cfg.wash.model_copy(update={"min_seen_fraction": 0.0})  # its views see two spots
    cfg = cfg.model_copy(update={"planner": cfg.planner.model_copy(update={"whole": whole}), "wash": wash})
    T_b = T_a @ transform_from_xyz_rpy((0, 0, 0), (0, 0, np.pi))  # the base on the other side of the bin
    poses = {0: T_a, 1: T_b}
    stations = [
        StationInfo(station=k, base_pose=PoseMsg.from_matrix(invert(T), "bin"), observation_index=0,
                    plans={"external": f"st{k}"}, viewpoints={"external": 1})
        for k, T in poses.items()
    ]  # fmt: skip
    plans = {
        (k, "external"): PlanLookupReply(
            hit=True,
            plan_id=f"st{k}",
            viewpoints=[PlannedViewpoint(index=0, camera_pose=CAM_POSE, joints=[0.1 * (k + 1)] * 6, faces=faces)],
            mesh_faces=mesh.n_faces,
        )
        for k, faces in ((0, np.flatnonzero(dirty_a).tolist()), (1, np.flatnonzero(dirty_b).tolist()))
    }
    dirty = dirty_a | dirty_b
    dm = {"seen_dirty": np.flatnonzero(dirty).tolist(), "seen_clean": []}
    return context(
        cfg, params=WASH, catalog=cat, identity=Identity(bin_type="case_study", T_base_bin=T_b),
        result=Result(dirt_map=dm), scan=Scan(plan=plans[(1, "external")]),
        stations=Stations(planned=stations, station_order=[0, 1], station_index=2, bin_poses=dict(poses), plans=plans),
    )  # fmt: skip


def test_a_whole_bin_round_washes_and_re_inspects_station_by_station_parking_again_where_needed(cfg, case) -> None:
    from cellctl.geometry.transforms import transform_from_xyz_rpy

    _, mesh, T_a = case
    dirty_a = _dirty(mesh, (0.2, -0.37, -0.15), (0, -1.0, 0))  # faces station 0
    dirty_b = _dirty(mesh, (-0.2, 0.37, -0.15), (0, 1.0, 0))  # the mirror spot: faces station 1
    ctx = _whole_ctx(cfg, case, dirty_a, dirty_b)
    run = ScriptedRun(ctx, _script(cfg))
    assert WashCheck()(run) == "wash"
    # the round's plan covers both spots, each from its own station: the base's station first
    (req,) = [m for _, o, m in run.calls if o == "wash_plan"]
    assert len(req.stations) == 2 and np.allclose(req.stations[0].matrix(), invert(ctx.stations.bin_poses[1]))
    assert ctx.wash.queue == [1, 0] and not ctx.wash.plan.unwashable
    assert WashStation()(run) == "wash" and Washing()(run) == "succeeded" and ctx.wash.queue == [0]
    n_first = ctx.wash.run["sweeps_run"]
    assert n_first == len(ctx.wash.station_sweeps[1])
    # station 0: park there; identifying measures the bin 1 cm and 0.5° off the scan's park
    assert WashStation()(run) == "park"
    assert ctx.stations.current_station().station == 0 and ctx.identity.approach is None and ctx.wash.parked == 0
    ctx.stations.bin_poses[0] = transform_from_xyz_rpy((0.01, 0.0, 0.0), (0, 0, np.radians(0.5))) @ T_a
    ctx.identity.T_base_bin = ctx.stations.bin_poses[0]
    assert WashStation()(run) == "wash" and Washing()(run) == "succeeded" and ctx.wash.queue == []
    replans = [m for _, o, m in run.calls if o == "wash_plan"][1:]
    assert len(replans) == 1 and np.allclose(replans[0].stations[0].matrix(), invert(ctx.stations.bin_poses[0]))
    assert set(replans[0].dirt_map["seen_dirty"]) >= set(np.flatnonzero(dirty_a).tolist())
    assert ctx.wash.run["sweeps_run"] > n_first and ctx.wash.run["replanned"][0]["station"] == 0
    # re-inspection: station 0 first (the base stands there), its view carried into the new park
    assert WashStation()(run) == "verify" and ctx.wash.verify_queue == [0, 1]
    assert Verifying()(run) == "next"
    (m0,) = [m for _, o, m in run.calls if o == "move"]
    assert m0.joints is None and np.allclose(
        m0.camera_pose.matrix(), ctx.stations.bin_poses[0] @ invert(T_a) @ CAM_POSE.matrix(), atol=1e-6
    )
    assert WashStation()(run) == "park" and ctx.wash.parked == 1  # back to station 1 (its pose measured again)
    assert WashStation()(run) == "verify" and Verifying()(run) == "succeeded"
    moves = [m for _, o, m in run.calls if o == "move"]
    assert len(moves) == 2 and list(moves[1].joints) == [0.2] * 6  # station 1's park is unchanged: its joints
    assert [(v.station, v.surface, v.wash_round) for v in ctx.wash.views] == [(0, "external", 1), (1, "external", 1)]
    (rec,) = ctx.wash.rounds
    assert rec.dirty_faces_before == (dirty_a | dirty_b).sum() and rec.dirty_faces_after == 0
    assert WashCheck()(run) == "done" and ctx.wash.result.verdict == "clean"


def test_a_later_round_plans_the_station_the_base_stands_at_at_the_pose_measured_at_this_park(cfg, case) -> None:
    """Round 2 starts where round 1's re-inspection parked the base: a park again since the scan.
    Its sweeps from there are planned at the bin pose measured at this park (no re-park, no replan
    follows); the other stations keep the scan's pose (they are replanned when the base parks)."""
    from cellctl.geometry.transforms import transform_from_xyz_rpy

    _, mesh, T_a = case
    dirty_a = _dirty(mesh, (0.2, -0.37, -0.15), (0, -1.0, 0))
    dirty_b = _dirty(mesh, (-0.2, 0.37, -0.15), (0, 1.0, 0))
    ctx = _whole_ctx(cfg, case, dirty_a, dirty_b)
    ctx.wash.scan_poses = dict(ctx.stations.bin_poses)
    ctx.wash.parked = 1
    done = {"sweeps_planned": 1, "sweeps_run": 1, "passes_run": 2, "washed_m2": 0.01, "covered_m2": 0.01}
    ctx.wash.rounds = [WashRound(round=1, dirty_faces_before=9, dirty_m2_before=0.01, **done)]
    scan_1 = ctx.stations.bin_poses[1]
    ctx.stations.bin_poses[1] = (
        transform_from_xyz_rpy((0.02, -0.01, 0.0), (0, 0, np.radians(1.0))) @ scan_1
    )  # parked again
    run = ScriptedRun(ctx, _script(cfg))
    assert WashCheck()(run) == "wash"
    (req,) = [m for _, o, m in run.calls if o == "wash_plan"]
    assert np.allclose(req.stations[0].matrix(), invert(ctx.stations.bin_poses[1]))  # this park's pose
    assert not np.allclose(req.stations[0].matrix(), invert(scan_1))
    assert np.allclose(req.stations[1].matrix(), invert(ctx.wash.scan_poses[0]))
    assert ctx.wash.queue[0] == 1 and WashStation()(run) == "wash"  # no parking: the base is there
    assert Washing()(run) == "succeeded"
    assert [o for _, o, _ in run.calls].count("wash_plan") == 1  # its sweeps were planned at this park


def test_a_re_inspection_view_whose_carried_pose_is_refused_is_taken_from_its_planned_joints(cfg, case) -> None:
    """Parked again since the scan, a view goes to its camera pose carried into the new park; when the
    arm refuses that pose (unreachable there), the planned joints take the view (nearly the same faces),
    so its faces are re-inspected this round and not left as they were."""
    from cellctl.geometry.transforms import transform_from_xyz_rpy

    _, mesh, T_a = case
    ctx = _whole_ctx(cfg, case, _dirty(mesh, (0.2, -0.37, -0.15), (0, -1.0, 0)), np.zeros(mesh.n_faces, bool))
    ctx.wash.scan_poses = dict(ctx.stations.bin_poses)
    ctx.stations.bin_poses[0] = transform_from_xyz_rpy((0.02, 0.0, 0.0), (0, 0, np.radians(1.0))) @ T_a  # parked again
    script = _script(cfg)

    def move(req):
        if req.camera_pose is not None:
            raise WorkerFailed("robot refused move: camera pose at [1.18, -0.10, 0.27] (base frame) is unreachable")
        return MoveReply(joints=list(req.joints), camera_pose=CAM_POSE), None

    script[("robot", "move")] = move
    run = ScriptedRun(ctx, script)
    (vp,) = ctx.stations.plans[(0, "external")].viewpoints
    Verifying._look(run, vp, 1, "external", 0)
    moves = [m for _, o, m in run.calls if o == "move"]
    assert [m.camera_pose is not None for m in moves] == [True, False] and list(moves[1].joints) == list(vp.joints)
    (v,) = ctx.wash.views
    assert v.error is None and v.label == "clean" and (v.station, v.wash_round) == (0, 1)
    # both refused: one view with the error, as before
    script[("robot", "move")] = lambda req: (_ for _ in ()).throw(WorkerFailed("in collision"))
    ctx.wash.views = []
    Verifying._look(run, vp, 1, "external", 0)
    (v,) = ctx.wash.views
    assert v.error == "in collision" and v.label is None


def test_a_dirty_view_is_laid_on_what_the_round_did_not_wash(cfg, case) -> None:
    """Coarse map: a re-inspection view that is still dirty marks the faces it sees that were dirty and
    got no sweep, not the washed ones; a view that sees only washed faces marks them dirty again."""
    _, mesh, _ = case
    ctx = _ctx(cfg, case, _dirty(mesh, (0.2, -0.37, -0.15), (0, -1.0, 0)))
    n = mesh.n_faces
    before = np.zeros(n, bool)
    before[[1, 2, 3]] = True
    washed = np.zeros(n, bool)
    washed[[1, 2]] = True
    ctx.scan.plan = PlanLookupReply(
        hit=True,
        plan_id="p",
        viewpoints=[
            PlannedViewpoint(index=0, camera_pose=CAM_POSE, joints=[0.1] * 6, faces=[1, 2, 3, 9]),
            PlannedViewpoint(index=1, camera_pose=CAM_POSE, joints=[0.2] * 6, faces=[1, 4]),
        ],
        mesh_faces=n,
    )
    from cellctl.messages import ViewpointResult

    def view(i: int) -> ViewpointResult:
        return ViewpointResult(index=i, camera_pose=CAM_POSE, label="dirty", p_dirty=0.9, wash_round=1)

    dm = Verifying._dirt_map(ctx, mesh, [view(0)], before, washed)
    assert dm["seen_dirty"] == [3] and dm["seen_clean"] == [1, 2, 9]  # face 3 got no sweep: the dirt is there
    imaged = imaged_faces(ctx, mesh, view(1))
    washed[list(imaged)] = True  # everything its image shows was washed: the wash did not explain it
    dm = Verifying._dirt_map(ctx, mesh, [view(1)], before, washed)
    assert dm["seen_dirty"] == [1, 4]


def _look_at(eye, target) -> np.ndarray:
    """Camera optical frame (z ahead, y down) at ``eye`` looking at ``target`` (bin frame)."""
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(z, x), z, eye
    return T


def test_a_dirty_view_whose_planned_faces_were_all_washed_marks_the_faces_its_image_shows(cfg, case) -> None:
    """The twin's seed-18 wash demo: powder left on two large leg faces (145 cm² each) that no plan
    lists kept a re-inspection view dirty after its planned faces were washed. The view marks the
    unwashed faces its image shows (a ray grid across the frame), so the next round washes them;
    not its own washed faces again."""
    from cellctl.geometry.camera import CameraModel
    from cellctl.messages import PoseMsg, ViewpointResult

    _, mesh, T_base_bin = case
    ctx = _ctx(cfg, case, _dirty(mesh, (0.2, -0.37, -0.15), (0, -1.0, 0)))
    n = mesh.n_faces
    leg = 4371  # a leg face of the case-study bin, normal -x
    c, nrm = mesh.centroids[leg], mesh.normals[leg]
    T_base_cam = T_base_bin @ _look_at(c + 0.4 * nrm, c)
    pose = PoseMsg.from_matrix(T_base_cam)
    listed = [1, 2]  # its plan's faces: elsewhere, all washed
    ctx.scan.plan = PlanLookupReply(
        hit=True,
        plan_id="p",
        viewpoints=[PlannedViewpoint(index=0, camera_pose=pose, joints=[0.1] * 6, faces=listed)],
        mesh_faces=n,
    )
    before = np.zeros(n, bool)
    before[listed] = True
    washed = before.copy()
    v = ViewpointResult(index=0, camera_pose=pose, label="dirty", p_dirty=0.9, wash_round=1)
    imaged = imaged_faces(ctx, mesh, v)
    assert leg in imaged and not set(listed) & imaged
    # only faces in front of the camera, on the side it faces, within 1.5 x the far depth of view
    d = (mesh.centroids[sorted(imaged)] - (c + 0.4 * nrm)) @ (-nrm)
    assert (d > 0).all() and (d < 1.5 * CameraModel.from_config(ctx.cfg.camera).dov[1] + 0.15).all()
    dm = Verifying._dirt_map(ctx, mesh, [v], before, washed)
    assert leg in dm["seen_dirty"] and not set(listed) & set(dm["seen_dirty"])
    assert set(dm["seen_dirty"]) == imaged
    # a clean view marks nothing beyond its own list
    clean = v.model_copy(update={"label": "clean", "p_dirty": 0.1})
    dm = Verifying._dirt_map(ctx, mesh, [clean], before, washed)
    assert dm["seen_dirty"] == [] and dm["seen_clean"] == listed


def test_the_re_inspection_map_fuses_heat_maps_with_the_scans_projection(cfg, case) -> None:
    """A re-inspection view with a heat map is fused as the scan's map is (``classifier.verdict``:
    projection, face cells, the ID board as occluder), so washing and inspection judge a face alike."""
    from cellctl.classify.heatmap import encode_heat, fuse_config
    from cellctl.geometry.camera import CameraModel
    from cellctl.messages import PoseMsg, ViewpointResult
    from cellctl.supervisor.steps.reporting import view_evidence

    cat, mesh, T_base_bin = case
    n = mesh.n_faces
    leg = 4371  # a large leg face of the case-study bin, normal -x
    c, nrm = mesh.centroids[leg], mesh.normals[leg]
    pose = PoseMsg.from_matrix(T_base_bin @ _look_at(c + 0.4 * nrm, c))
    # hotter to the frame's right: where each projection reads the heat on the face tells them apart
    heat = np.tile(np.linspace(0.02, 0.99, 16), (16, 1))
    v = ViewpointResult(
        index=0, camera_pose=pose, label="dirty", p_dirty=0.99, wash_round=1, heatmap=encode_heat(heat), heat_grid=16
    )
    maps = {}
    for projection in ("samples", "patches"):
        vc = cfg.classifier.verdict.model_copy(update={"projection": projection})
        c2 = cfg.model_copy(update={"classifier": cfg.classifier.model_copy(update={"verdict": vc})})
        ctx = _ctx(c2, case, np.zeros(n, bool))
        ctx.scan.plan = PlanLookupReply(
            hit=True,
            plan_id="p",
            viewpoints=[PlannedViewpoint(index=0, camera_pose=pose, joints=[0.1] * 6, faces=[leg])],
            mesh_faces=n,
        )
        dm = Verifying._dirt_map(ctx, mesh, [v], np.zeros(n, bool), np.zeros(n, bool))
        ref = fuse_config(
            view_evidence(ctx.scan.plan, [v], T_base_bin),
            mesh,
            CameraModel.from_config(c2.camera),
            vc,
            cat.get("case_study"),
        )
        assert dm == ref.as_json()
        maps[projection] = dm
    # the two projections give different maps here, so the equality above is the config's, not chance
    assert maps["samples"] != maps["patches"]


def test_a_sweep_whose_start_has_no_path_is_run_from_its_other_end(cfg, case) -> None:
    dirty = _dirty(case[1], (0.2, -0.37, -0.15), (0, -1.0, 0))
    ctx = _ctx(cfg, case, dirty)
    script = _script(cfg)
    run = ScriptedRun(ctx, script)
    assert WashCheck()(run) == "wash"
    firsts = {tuple(sw.joints[0]) for sw in ctx.wash.plan.sweeps if len(sw.joints) > 1}

    def one_way(req):
        sw = req.sweeps[0]
        if tuple(sw.joints[0]) in firsts:
            raise WorkerFailed("no collision-free path from home to the sweep's start within 3 s", role="robot")
        return WashReply(sweeps_run=1, passes_run=sw.passes, joints=sw.joints[-1]), None

    script[("robot", "wash")] = one_way
    assert Washing()(run) == "succeeded"
    n = len(ctx.wash.plan.sweeps)
    assert ctx.wash.run["sweeps_run"] == n and ctx.wash.run["refused"] == []
    assert sum(1 for _, o, _ in run.calls if o == "wash") == n + len(firsts)


def _relook_run(cfg, case, second: ClassifyReply):
    """A washed spot whose one re-inspection view comes back certain dirty, its re-look ``second``
    (re-looks confirm dirty views: ``classifier.relook.confirm_dirty: on``)."""
    from cellctl.config import load_config

    cfg = load_config(None, [*_overrides(cfg), "classifier.relook.confirm_dirty=on"])
    _, mesh, _ = case
    dirty = _dirty(mesh, (0.2, -0.37, -0.15), (0, -1.0, 0))
    ctx = _ctx(cfg, case, dirty)
    script = _script(cfg)
    replies = [ClassifyReply(label="dirty", p_dirty=0.9, model_id="m"), second]
    # later rounds: every view and re-look as the re-look says
    script[("classifier", "classify")] = lambda req: (replies.pop(0) if len(replies) > 1 else replies[0], None)
    run = ScriptedRun(ctx, script)
    assert WashCheck()(run) == "wash" and WashStation()(run) == "wash" and Washing()(run) == "succeeded"
    assert WashStation()(run) == "verify" and Verifying()(run) == "succeeded"
    return ctx, run, dirty


def _overrides(cfg) -> list[str]:
    """The fixture config's overrides again (its port and folders), to load a variant of it."""
    ep = cfg.bus.listen[0]
    return [
        f'bus.listen=["{ep}"]',
        f'bus.connect=["{ep}"]',
        f"recording.dir={cfg.recording.dir}",
        f"planner.plans_dir={cfg.planner.plans_dir}",
        "robot.settle_s=0",
        "planner.whole.enabled=false",  # as the fixture: one station's plan, a few faces seen
        "classifier.verdict.min_seen_fraction={}",
    ]


def test_a_dirty_re_inspection_view_a_certain_clean_re_look_overrules_ends_clean(cfg, case) -> None:
    """The scan's confirm-dirty rule in the re-inspection: a view still called dirty after the wash is
    imaged again from a nearby pose (a camera pose, not the planned joints); certain clean there, its
    faces are clean and the round ends the bin clean."""
    ctx, run, _ = _relook_run(cfg, case, ClassifyReply(label="clean", p_dirty=0.02, model_id="m"))
    moves = [m for _, o, m in run.calls if o == "move"]
    assert len(moves) == 2 and moves[0].joints is not None and moves[1].camera_pose is not None
    assert not np.allclose(moves[1].camera_pose.matrix(), CAM_POSE.matrix())  # moved by the re-look swing
    assert [(v.relook_of, v.label, v.wash_round) for v in ctx.wash.views] == [(None, "dirty", 1), (0, "clean", 1)]
    (rec,) = ctx.wash.rounds
    assert rec.dirty_faces_after == 0 and rec.reinspected_views == 2
    assert WashCheck()(run) == "done" and ctx.wash.result.verdict == "clean"


def test_a_dirty_re_inspection_view_its_re_look_confirms_keeps_the_leftover_dirty(cfg, case) -> None:
    """Real dirt left after the wash is seen from the re-look pose too: the faces stay dirty and the
    loop washes again, and once the rounds are spent the bin ends ``dirty``, never clean."""
    ctx, run, dirty = _relook_run(cfg, case, ClassifyReply(label="dirty", p_dirty=0.85, model_id="m"))
    (rec,) = ctx.wash.rounds
    assert rec.dirty_faces_after == dirty.sum()  # every washed face the dirty view sees (none unwashed)
    assert WashCheck()(run) == "wash"  # round 2
    for _ in range(cfg.wash.max_rounds - 1):
        assert WashStation()(run) == "wash" and Washing()(run) == "succeeded"
        assert WashStation()(run) == "verify" and Verifying()(run) == "succeeded"
        if len(ctx.wash.rounds) < cfg.wash.max_rounds:
            assert WashCheck()(run) == "wash"
    assert WashCheck()(run) == "done" and ctx.result.verdict == "dirty" and ctx.wash.result.verdict == "dirty"
    assert ctx.wash.result.remaining_faces and "after 3 wash round(s)" in ctx.wash.result.reason


def test_an_uncertain_re_inspection_view_is_re_looked_even_without_confirming(cfg, case) -> None:
    """Without confirm-dirty (a single-station cycle's default) only uncertain views are re-looked,
    and the two are decided as the scan decides them."""
    _, mesh, _ = case
    ctx = _ctx(cfg, case, _dirty(mesh, (0.2, -0.37, -0.15), (0, -1.0, 0)))
    script = _script(cfg)
    replies = iter(
        [
            ClassifyReply(label="dirty", p_dirty=0.55, uncertain=True, model_id="m"),
            ClassifyReply(label="clean", p_dirty=0.01, model_id="m"),
        ]
    )
    script[("classifier", "classify")] = lambda req: (next(replies), None)
    run = ScriptedRun(ctx, script)
    assert WashCheck()(run) == "wash" and WashStation()(run) == "wash" and Washing()(run) == "succeeded"
    assert WashStation()(run) == "verify" and Verifying()(run) == "succeeded"
    assert [v.relook_of for v in ctx.wash.views] == [None, 0]
    # decided like the scan's views (classifying.Classifying._view_labels), not by a rule of its own
    from cellctl.supervisor.steps.classifying import Classifying

    (label,) = Classifying._view_labels(ctx.wash.views, False).values()
    assert (ctx.wash.rounds[0].dirty_faces_after > 0) == (label == "dirty")
    ctx2 = _ctx(cfg, case, _dirty(mesh, (0.2, -0.37, -0.15), (0, -1.0, 0)))
    run2 = ScriptedRun(ctx2, _script(cfg, label="dirty"))  # certain dirty, not confirming: no re-look
    assert WashCheck()(run2) == "wash" and WashStation()(run2) == "wash" and Washing()(run2) == "succeeded"
    assert WashStation()(run2) == "verify" and Verifying()(run2) == "succeeded"
    assert [v.relook_of for v in ctx2.wash.views] == [None] and ctx2.wash.rounds[0].dirty_faces_after > 0


def test_clean_needs_the_configured_share_of_the_bin_seen(cfg, case) -> None:
    """No dirt seen on a map that saw too little of the bin is not a clean bin: ``incomplete``, reason
    "unverified", the seen share reported; the same map seeing enough of the bin ends clean, unless a
    surface is below ``classifier.verdict.min_seen_fraction`` (``incomplete`` with the fractions)."""
    _, mesh, _ = case
    n = mesh.n_faces
    a = mesh.areas
    order = np.argsort(-a)  # the largest faces first: a known share of the area
    k = int(np.searchsorted(np.cumsum(a[order]) / a.sum(), 0.5)) + 1
    half = sorted(order[:k].tolist())  # just over half the bin's area
    ctx = _ctx(cfg, case, np.zeros(n, bool), min_seen=0.6)
    ctx.result.dirt_map = {"seen_dirty": [], "seen_clean": half}
    run = ScriptedRun(ctx, _script(cfg))
    assert WashCheck()(run) == "done" and run.calls == []
    assert (
        ctx.result.verdict == "incomplete"
        and ctx.wash.result.verdict == "incomplete"
        and ctx.result.reason == ctx.wash.result.reason
    )
    assert ctx.wash.result.reason.startswith("unverified")
    assert 0.5 <= ctx.wash.result.seen_fraction < 0.6 and ctx.wash.result.min_seen_fraction == 0.6
    assert f"{ctx.wash.result.seen_fraction:.0%}" in ctx.wash.result.reason
    ctx = _ctx(cfg, case, np.zeros(n, bool), min_seen=0.5)
    ctx.result.dirt_map = {"seen_dirty": [], "seen_clean": half}
    run = ScriptedRun(ctx, _script(cfg))
    assert WashCheck()(run) == "done"
    assert ctx.result.verdict == "clean" and ctx.wash.result.verdict == "clean" and ctx.wash.result.reason is None
    assert ctx.wash.result.seen_fraction >= 0.5
    seen = ctx.result.coverage_by_surface
    assert set(seen) == {"external", "internal"} and all(0 < f < 1 for f in seen.values())
    # the same map against a per-surface minimum above what it saw of the internal surface
    ctx = _ctx(cfg, case, np.zeros(n, bool), min_seen=0.5)
    vc = cfg.classifier.verdict.model_copy(update={"min_seen_fraction": {"internal": seen["internal"] + 0.01}})
    ctx.cfg = ctx.cfg.model_copy(update={"classifier": cfg.classifier.model_copy(update={"verdict": vc})})
    ctx.result.dirt_map = {"seen_dirty": [], "seen_clean": half}
    assert WashCheck()(ScriptedRun(ctx, _script(cfg))) == "done"
    assert ctx.result.verdict == "incomplete" and ctx.wash.result.verdict == "incomplete"
    assert (
        ctx.wash.result.reason.startswith("incomplete: no dirt seen, but internal")
        and "external" not in ctx.wash.result.reason
    )
    # a heat-map dirt map: seen is where a face has a probability
    p = np.full(n, np.nan)
    p[half] = 0.01
    ctx = _ctx(cfg, case, np.zeros(n, bool), min_seen=0.6)
    from cellctl.classify.heatmap import FaceMap

    ctx.result.dirt_map = FaceMap(
        p=np.nan_to_num(p), seen=~np.isnan(p), dirty=np.zeros(n, bool), dirty_area_m2=0.0
    ).as_json()
    assert WashCheck()(ScriptedRun(ctx, _script(cfg))) == "done" and ctx.wash.result.reason.startswith("unverified")
