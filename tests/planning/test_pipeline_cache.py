"""The whole pipeline on a small box bin, the plan cache and the pose-tolerance lookup."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from cellctl.errors import PlanCacheError
from cellctl.geometry.transforms import invert, rotation_about, transform_from
from cellctl.planning.adjust import lookup_plan
from cellctl.planning.collision import PlanningWorld
from cellctl.planning.pipeline import PlanParams, base_pose_from_xyz_yaw, make_plan
from cellctl.planning.planfile import list_plans, plan_path, read_plan, write_plan


@pytest.fixture(scope="module")
def ext_plan(box, robot, T_bin_base):
    return make_plan(
        box, T_bin_base, PlanParams(surface="external", seed_pct=6, sa_iterations=1500), robot, bin_type="box"
    )


def test_external_plan_counts_shrink_stage_by_stage(ext_plan):
    c = ext_plan.counts
    assert ext_plan.reason is None
    assert c.generated >= c.filtered >= c.reachable >= c.greedy >= c.annealed > 0
    assert c.optimal_cover <= c.greedy
    assert c.annealed == round(0.85 * c.greedy)
    a = ext_plan.area
    assert 0 < a.visible_selected_m2 <= a.visible_all_m2 <= a.mesh_m2
    assert set(ext_plan.to_json()["times_s"]) >= {
        "generate_filter",
        "reachability",
        "visibility",
        "selection",
        "distance_matrix",
        "ordering",
        "total",
    }
    assert ext_plan.tour_cost > 0


def test_viewpoint_joints_reach_their_camera_poses_collision_free(ext_plan, box, robot, T_bin_base):
    vps = ext_plan.viewpoints
    Q = np.array([v.q for v in vps])
    T_base_cam = robot.fk_cam(Q)
    assert np.allclose(T_base_cam, np.array([v.T_base_cam for v in vps]), atol=1e-6)
    T_bin_cam = np.array([v.T_bin_cam for v in vps])
    assert np.allclose(T_bin_base @ T_base_cam, T_bin_cam, atol=1e-6)
    assert robot.within_limits(Q).all()
    assert PlanningWorld(box, robot, T_bin_base, margin=ext_plan.params.margin).robot_free(Q).all()
    ext_faces = set(np.flatnonzero(~box.internal).tolist())
    assert all(set(v.faces.tolist()) <= ext_faces and len(v.faces) for v in vps)
    # the far side of the box (+y outer wall) faces away from the robot: no viewpoint sees it
    far = {f for f in ext_faces if box.normals[f, 1] > 0.9}
    assert not any(far & set(v.faces.tolist()) for v in vps)


def test_internal_surface_plans_and_misses_part_of_the_cavity(box, robot, T_bin_base):
    plan = make_plan(box, T_bin_base, PlanParams(surface="internal", seed_pct=8, sa_iterations=1000), robot)
    assert plan.reason is None and plan.viewpoints
    assert all(box.internal[v.faces].all() for v in plan.viewpoints)
    assert 0 < plan.coverage < 1.0


def test_unreachable_base_gives_an_empty_plan_with_the_reason(box, robot):
    far = base_pose_from_xyz_yaw(4.0, 0.0, -0.1, 0.0)
    plan = make_plan(box, far, PlanParams(seed_pct=5), robot)
    assert plan.is_empty and plan.viewpoints == () and "distance" in plan.reason and "1.3 m" in plan.reason
    assert plan.sa is None and "sa" not in plan.to_json() and plan.counts.filtered == 0


def test_plan_file_roundtrip_and_damage_detection(ext_plan, tmp_path):
    p = write_plan(ext_plan, plan_path(tmp_path, ext_plan))
    assert read_plan(p).to_json() == json.loads(json.dumps(ext_plan.to_json()))
    assert [f.name for f in p.parent.iterdir()] == [p.name]  # no temp files left behind
    text = p.read_text()
    p.write_text(text.replace('"coverage":', '"coverage":1', 1))
    with pytest.raises(PlanCacheError, match="damaged: sha256"):
        read_plan(p)
    p.write_text(text[: len(text) // 2])
    with pytest.raises(PlanCacheError, match="not JSON"):
        read_plan(p)
    plans, skipped = list_plans(tmp_path, "box", "external")
    assert plans == [] and len(skipped) == 1


def _moved(T_base_bin: np.ndarray, dx_m: float, dyaw_deg: float) -> np.ndarray:
    return T_base_bin @ transform_from(rotation_about((0, 0, 1), np.radians(dyaw_deg)), (dx_m, 0.0, 0.0))


def test_lookup_hit_adjust_and_misses(ext_plan, box, robot, T_bin_base, tmp_path):
    write_plan(ext_plan, plan_path(tmp_path, ext_plan))
    T_base_bin = invert(T_bin_base)
    same = lookup_plan(tmp_path, "box", "external", T_base_bin, box, robot, 20.0, 2.0)
    assert same.hit and not same.adjusted and same.plan_id == ext_plan.plan_id
    assert len(same.viewpoints) == len(ext_plan.viewpoints)

    # The base parked robust_m off along its x axis: the planner kept only viewpoints that stay
    # reachable (IK next to the planned joints, collision-free) at exactly this parking error,
    # so the adjusted lookup must hit.
    dx = ext_plan.params.robust_m
    parked = invert(T_bin_base @ transform_from(np.eye(3), (dx, 0.0, 0.0)))
    near = lookup_plan(tmp_path, "box", "external", parked, box, robot, 50.0, 2.0)
    assert near.hit, near.reason
    assert near.adjusted and abs(near.translation_mm - 1000.0 * dx) < 0.5 and near.rotation_deg < 1e-6
    q = np.array([v.q for v in near.viewpoints])
    q0 = np.array([v.q for v in ext_plan.viewpoints])
    assert np.abs(q - q0).max() < 0.5 and np.abs(q - q0).max() > 1e-4  # re-solved, not copied
    assert np.allclose(robot.fk_cam(q), np.array([v.T_base_cam for v in near.viewpoints]), atol=1e-6)
    T_bin_cam = np.array([v.T_bin_cam for v in ext_plan.viewpoints])
    assert np.allclose(parked @ T_bin_cam, np.array([v.T_base_cam for v in near.viewpoints]), atol=1e-9)

    # Within a (generous) tolerance but 2 m away: the viewpoints are out of the arm's reach.
    gone = invert(T_bin_base @ transform_from(np.eye(3), (2.0, 0.0, 0.0)))
    out = lookup_plan(tmp_path, "box", "external", gone, box, robot, 5000.0, 2.0)
    assert not out.hit and not out.viewpoints
    assert "cannot be adjusted" in out.reason and "out of reach" in out.reason, out.reason

    every = lookup_plan(tmp_path, "box", "external", T_base_bin, box, robot, 20.0, 2.0, use_all=True)
    assert every.hit and len(every.viewpoints) == ext_plan.counts.reachable > len(same.viewpoints)

    far = lookup_plan(tmp_path, "box", "external", _moved(T_base_bin, 0.05, 0.0), box, robot, 20.0, 2.0)
    assert not far.hit and "tolerance is 20 mm" in far.reason and abs(far.translation_mm - 50.0) < 0.5

    box2 = dataclasses.replace(box, sha256="0" * 64)
    changed = lookup_plan(tmp_path, "box", "external", T_base_bin, box2, robot, 20.0, 2.0)
    assert not changed.hit and "mesh hash" in changed.reason

    none = lookup_plan(tmp_path, "tote", "external", T_base_bin, box, robot, 20.0, 2.0)
    assert not none.hit and "no plan for bin type 'tote'" in none.reason
