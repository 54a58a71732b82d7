"""The planner worker's wash_plan op (cellctl.washing.service): the plan as wire data, bad input named."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.config import load_config
from cellctl.errors import ConfigError, PlanningError
from cellctl.geometry.catalog import load_catalog
from cellctl.messages import PoseMsg, WashPlanRequest
from cellctl.sim.ground_truth import PowderField
from cellctl.sim.scene import HOME_JOINTS, nominal_T_bin_base
from cellctl.surface import EXTERNAL
from cellctl.washing.service import MeshCache, wash_plan_reply


@pytest.fixture(scope="module")
def setup():
    cfg = load_config()
    cat = load_catalog(cfg.path(cfg.catalog), cfg.root)
    mesh = cat.load_mesh("case_study")
    station = PoseMsg.from_matrix(nominal_T_bin_base(cat.get("case_study"), mesh), "bin")
    return cfg, MeshCache(cfg), mesh, station


def _req(station: PoseMsg, dirt_map: dict | None, bin_type: str = "case_study") -> WashPlanRequest:
    return WashPlanRequest(bin_type=bin_type, stations=[station], q_start=HOME_JOINTS.tolist(), dirt_map=dirt_map)


def test_a_plan_travels_as_sweeps_with_joints_spots_and_the_faces_they_cover(setup) -> None:
    cfg, meshes, mesh, station = setup
    f = PowderField(np.array([[0.2, -0.37, -0.15]]), np.array([0.04]), np.array([EXTERNAL], np.uint8),
                    np.array([[0, -1.0, 0]]), 7)  # fmt: skip
    dirty = np.flatnonzero(f.dirty_faces(mesh)).tolist()
    reply = wash_plan_reply(cfg, meshes, _req(station, {"seen_dirty": dirty}))
    assert reply.reason is None and reply.sweeps and not reply.unwashable
    assert reply.dirty == dirty and set(dirty) <= set(reply.covered) <= set(reply.targets)
    for sw in reply.sweeps:
        assert len(sw.spots) == len(sw.axes) == len(sw.joints) and sw.passes >= 1
        # the spots lie on the wall the jet faces (y = -0.37 in the bin frame), the jet towards it
        assert np.allclose(np.asarray(sw.spots)[:, 1], -0.37, atol=0.03)
        assert np.all(np.asarray(sw.axes)[:, 1] > 0.5)
    assert reply.summary["sweeps"] == len(reply.sweeps) and reply.cpu_s > 0


def test_no_dirt_map_is_a_reason_and_no_sweeps(setup) -> None:
    cfg, meshes, _, station = setup
    reply = wash_plan_reply(cfg, meshes, _req(station, None))
    assert reply.sweeps == [] and "no dirt map" in reply.reason


def test_bad_requests_are_refused_naming_the_value(setup) -> None:
    cfg, meshes, _, station = setup
    with pytest.raises(ConfigError, match="no_such_bin"):
        wash_plan_reply(cfg, meshes, _req(station, {"seen_dirty": [1]}, "no_such_bin"))
    base = PoseMsg(position=station.position, orientation=station.orientation, frame_id="base")
    with pytest.raises(PlanningError, match="frame_id 'base'; expected 'bin'"):
        wash_plan_reply(cfg, meshes, _req(base, {"seen_dirty": [1]}))
    with pytest.raises(PlanningError, match="outside the mesh"):
        wash_plan_reply(cfg, meshes, _req(station, {"seen_dirty": [10**6]}))
