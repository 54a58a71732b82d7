"""A station that cannot see the board gets the bin pose carried through the base's reported motion.

The twin's base reports where it parked (its localisation: truth plus ``base.localisation_error_*``)
in the approach reply; identifying keeps the bin in the base's map frame where it measured it and,
at a station without the board, expresses it in the new park's frame (``base_odometry``). Without
a report it falls back to the planned station pose (``carried_over``).
"""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.geometry.transforms import invert, pose_error, transform_from_xyz_rpy
from cellctl.messages import ApproachReply, ApproachRequest, PoseMsg, StationInfo
from cellctl.sim import scene
from cellctl.supervisor.steps.approaching import Approaching
from cellctl.supervisor.steps.identifying import Identifying
from tests.supervisor._scripted import ScriptedRun, context
from tests.workers.test_station_park import robot  # noqa: F401 - the sim arm (fast drive)


def _station(bt, mesh, deg: float) -> np.ndarray:
    return transform_from_xyz_rpy((0, 0, 0), (0, 0, np.radians(deg))) @ scene.nominal_T_bin_base(bt, mesh)


def test_the_twin_base_reports_its_park_within_its_localisation_error(robot) -> None:  # noqa: F811
    bt = robot.catalog.get("case_study")
    mesh = robot.catalog.load_mesh("case_study")
    b = robot.cfg.base
    errs = []
    for deg in (0.0, 90.0, 180.0):
        reply = robot.approach(
            ApproachRequest(park=True, base_pose=PoseMsg.from_matrix(_station(bt, mesh, deg), "bin"), observe=False)
        )
        assert reply.base_pose is not None and reply.base_pose.frame_id == "map"
        truth = robot.sim_state().world_T_base.matrix()
        dt, dr = pose_error(truth, reply.base_pose.matrix())
        assert dt <= b.localisation_error_m + 1e-9 and np.degrees(dr) <= b.localisation_error_deg + 1e-9
        errs.append(dt)
        # the report holds while parked: an approach without a park reports the same pose
        again = robot.approach(ApproachRequest(park=False, observe=False))
        assert np.allclose(again.base_pose.matrix(), reply.base_pose.matrix())
    assert max(errs) > 0  # an error is drawn, not the truth handed over


def test_a_manual_base_reports_no_pose(robot) -> None:  # noqa: F811
    robot.cfg.base.backend = "manual"
    reply = robot.approach(ApproachRequest(park=True, observe=False))
    assert reply.base_pose is None


def test_odometry_carries_the_measured_pose_to_the_next_park_within_twice_the_localisation_error(robot) -> None:  # noqa: F811
    """The sim's truth end to end: measured at one park, carried to a park on the other side."""
    bt = robot.catalog.get("case_study")
    mesh = robot.catalog.load_mesh("case_study")
    b = robot.cfg.base
    r1 = robot.approach(ApproachRequest(park=True, observe=False))
    T_base_bin1 = scene.T_base_bin_of(robot.scenario, bt)  # a perfect measurement at the first park
    T_map_bin = r1.base_pose.matrix() @ T_base_bin1
    r2 = robot.approach(
        ApproachRequest(park=True, base_pose=PoseMsg.from_matrix(_station(bt, mesh, 180.0), "bin"), observe=False)
    )
    truth = scene.T_base_bin_of(robot.scenario, bt)
    carried = invert(r2.base_pose.matrix()) @ T_map_bin
    planned = invert(_station(bt, mesh, 180.0))
    dt, dr = pose_error(truth, carried)
    # two reports' errors, and the yaw errors' lever over the base-to-bin distance
    lever = float(np.linalg.norm(truth[:2, 3])) + float(np.linalg.norm(T_base_bin1[:2, 3]))
    assert dt <= 2 * b.localisation_error_m + np.radians(b.localisation_error_deg) * lever + 1e-9
    assert np.degrees(dr) <= 2 * b.localisation_error_deg + 1e-9
    # what the planned station pose would have said: the parking error, several times larger
    assert pose_error(truth, planned)[0] > dt


def _reply(T_map_base: np.ndarray | None) -> ApproachReply:
    return ApproachReply(
        joints=[0.0] * 6,
        flange_pose=PoseMsg.from_matrix(np.eye(4)),
        camera_pose=PoseMsg.from_matrix(np.eye(4)),
        base_pose=None if T_map_base is None else PoseMsg.from_matrix(T_map_base, "map"),
    )


def _blind_station() -> StationInfo:
    T_bin_base = transform_from_xyz_rpy((0.0, 1.2, 0.0), (0.0, 0.0, -np.pi / 2))
    return StationInfo(
        station=1,
        base_pose=PoseMsg.from_matrix(T_bin_base, "bin"),
        observation_index=None,
        identify_reason="board not visible",
        plans={"external": "p1"},
        viewpoints={"external": 3},
    )


def test_identifying_carries_the_bin_through_the_reported_base_motion(cfg) -> None:
    ctx = context(cfg)
    st = _blind_station()
    ctx.stations.planned, ctx.stations.station_order, ctx.identity.bin_type = [st], [1], "case_study"
    # measured earlier: the bin 1 m ahead of a base parked at the map's origin
    ctx.stations.T_map_bin = transform_from_xyz_rpy((1.0, 0.0, 0.0), (0, 0, 0.1))
    T_map_base2 = transform_from_xyz_rpy((1.3, 1.1, 0.0), (0, 0, -np.pi / 2 + 0.02))
    run = ScriptedRun(ctx, {("robot", "approach"): (_reply(T_map_base2), None)})
    assert Approaching()(run) == "succeeded"
    assert np.allclose(ctx.stations.T_map_base, T_map_base2)
    assert Identifying()(run) == "succeeded"
    assert ctx.stations.pose_source[1] == "base_odometry"
    assert np.allclose(
        T_map_base2 @ ctx.identity.T_base_bin, ctx.stations.T_map_bin
    )  # the same bin, seen from the new park
    assert not np.allclose(ctx.identity.T_base_bin, invert(st.base_pose.matrix()))
    assert any("carried from the last measured station" in t for _, t in run.events)


def test_without_a_base_report_the_planned_station_pose_is_used(cfg) -> None:
    ctx = context(cfg)
    st = _blind_station()
    ctx.stations.planned, ctx.stations.station_order, ctx.identity.bin_type = [st], [1], "case_study"
    ctx.stations.T_map_bin = transform_from_xyz_rpy((1.0, 0.0, 0.0), (0, 0, 0))
    ctx.stations.T_map_base = np.eye(4)  # the previous park's report must not stand for this park's
    run = ScriptedRun(ctx, {("robot", "approach"): (_reply(None), None)})
    assert Approaching()(run) == "succeeded"
    assert ctx.stations.T_map_base is None
    assert Identifying()(run) == "succeeded"
    assert ctx.stations.pose_source[1] == "carried_over"
    assert np.allclose(ctx.identity.T_base_bin, invert(st.base_pose.matrix()))


def test_a_measured_station_keeps_the_bin_in_the_map_frame(cfg, monkeypatch) -> None:
    T_map_base = transform_from_xyz_rpy((0.2, -0.3, 0.0), (0, 0, 0.3))
    T_base_bin = transform_from_xyz_rpy((1.0, 0.05, 0.2), (0, 0, 0.01))

    class Ident:
        bin_type = "case_study"

        def __init__(self) -> None:
            self.T_base_bin = T_base_bin

    cfg.supervisor.identify_views = 1
    ctx = context(cfg)
    ctx.identity.approach = _reply(T_map_base)
    ctx.stations.T_map_base = T_map_base
    monkeypatch.setattr(Identifying, "_view", lambda self, run, T: Ident())
    assert Identifying()(ScriptedRun(ctx, {})) == "succeeded"
    assert np.allclose(ctx.stations.T_map_bin, T_map_base @ T_base_bin)


@pytest.mark.slow  # two whole-bin plans of a box: ~20 CPU s
def test_the_planner_keeps_more_clearance_where_the_board_is_not_visible(cfg) -> None:
    """A station without the board (here: a mesh without a catalog board, so every station) keeps
    ``odometry_m`` more clearance in every planned configuration; the plan keeps its own margin."""
    from cellctl.planning.collision import PlanningWorld
    from cellctl.planning.plan import PlanParams
    from cellctl.planning.robot import RobotModel
    from cellctl.planning.shapes import open_box_bin
    from cellctl.planning.stations import StationParams
    from cellctl.planning.whole import WholeParams, plan_whole

    box, model = open_box_bin(), RobotModel.from_config(cfg)
    fast = PlanParams(seed_pct=4.0, seed=3, sa_iterations=500, n_roll=8)
    extra = 0.03  # large, so the check bites on a box's internal views

    def clearances(odometry_m: float) -> list[bool]:
        wp = plan_whole(box, WholeParams(plan=fast, stations=StationParams(candidates=4), odometry_m=odometry_m), model)
        out = []
        for st in wp.stations:
            assert st.identify_T_bin_cam is None  # no board: the carried pose
            world = PlanningWorld(box, model, st.T_bin_base, margin=fast.margin + extra)
            for plan in st.plans.values():
                assert plan.params.margin == fast.margin  # what the lookup's adjustment checks
                Q = np.array([v.q for v in plan.viewpoints])
                out += list(world.robot_free(Q)) if len(Q) else []
        return out

    kept = clearances(extra)
    assert kept and all(kept)
    assert not all(clearances(0.0))  # without it some configuration is closer than that
