"""The planner pool plans wash rounds: a real `cellctl router` with the job queue and a real pool
worker (`cellctl worker planner --backend pool`) answer `cell/<id>/planner/wash_plan` for any cell
of the pool, with the same plan a cell's own planner worker makes, and refuse bad input by name."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.bus import keys
from cellctl.bus.codec import decode, decode_as, encode
from cellctl.config import load_config
from cellctl.geometry.catalog import load_catalog
from cellctl.geometry.transforms import invert
from cellctl.messages import ErrorReply, PoseMsg, WashPlanReply, WashPlanRequest
from cellctl.sim.ground_truth import PowderField
from cellctl.sim.scene import HOME_JOINTS, nominal_T_bin_base
from cellctl.surface import EXTERNAL
from cellctl.washing.service import MeshCache, wash_plan_reply
from tests.cluster.test_pool import Pool


def _request(bin_type: str = "case_study") -> WashPlanRequest:
    cfg = load_config()
    cat = load_catalog(cfg.path(cfg.catalog), cfg.root)
    mesh = cat.load_mesh("case_study")
    T_bin_base = nominal_T_bin_base(cat.get("case_study"), mesh)
    spot = PowderField(
        np.array([[0.2, -0.37, -0.15]]), np.array([0.04]), np.array([EXTERNAL], np.uint8), np.array([[0, -1.0, 0]]), 7
    )
    return WashPlanRequest(
        bin_type=bin_type,
        stations=[PoseMsg.from_matrix(T_bin_base, "bin")],
        q_start=HOME_JOINTS.tolist(),
        dirt_map={"seen_dirty": np.flatnonzero(spot.dirty_faces(mesh)).tolist()},
    )


@pytest.fixture(scope="module")
def pool(tmp_path_factory: pytest.TempPathFactory):
    p = Pool(tmp_path_factory.mktemp("pool"), workers=1)
    try:
        try:
            p.wait_workers(1, timeout=60)
        except AssertionError:
            # under load the worker can start before the router listens (it exits naming the endpoint)
            p.start_worker(0)
            p.wait_workers(1)
        yield p
    finally:
        p.close()


def test_a_pool_worker_plans_any_cells_wash_as_the_cells_own_planner_would(pool: Pool) -> None:
    req = _request()
    assert invert(req.stations[0].matrix()).shape == (4, 4)
    own = wash_plan_reply(load_config(), MeshCache(load_config()), req)
    for cell in ("cell1", "cell2"):
        key = keys.planner_wash_plan_any().replace("*", cell)
        reply = decode_as(WashPlanReply, pool.get(key, req, timeout=120))
        assert reply.sweeps and reply.reason is None and not reply.unwashable
        assert reply.dirty == own.dirty and reply.covered == own.covered
        assert [s.joints for s in reply.sweeps] == [s.joints for s in own.sweeps]  # seeded: the same plan


def test_a_pool_wash_plan_for_an_unknown_bin_is_refused_by_name(pool: Pool) -> None:
    key = keys.planner_wash_plan_any().replace("*", "cell1")
    (reply,) = list(pool.session.get(key, payload=encode(_request("no_such_bin")), timeout=60))
    assert reply.err is not None  # a refusal is the query's error reply, as every worker op's
    err = decode(reply.err.payload.to_bytes())
    assert isinstance(err, ErrorReply) and "no_such_bin" in err.reason
