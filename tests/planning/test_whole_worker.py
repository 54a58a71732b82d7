"""The planner worker's whole-bin jobs: every station plan in the cache, found by its station's pose."""

from __future__ import annotations

import numpy as np

from cellctl.geometry.transforms import invert
from cellctl.messages import PlanJobRequest, PlanLookupRequest, PoseMsg
from cellctl.planning.planfile import list_plans, read_document
from cellctl.workers.planner import PlannerService
from tests.conftest import free_port
from tests.planning.test_worker import _cfg, box_catalog  # noqa: F401 - the catalog fixture

_T_BIN_BASE = np.array([[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, -0.95], [0.0, 0.0, 1.0, -0.1], [0, 0, 0, 1.0]])


def test_whole_job_writes_station_plans_each_found_at_its_station(tmp_path, box_catalog):  # noqa: F811
    cfg = _cfg(tmp_path, box_catalog, free_port())
    cfg = cfg.model_copy(
        update={
            "planner": cfg.planner.model_copy(
                update={"whole": cfg.planner.whole.model_copy(update={"candidates": 4, "inner_candidates": 2})}
            )
        }
    )
    svc = PlannerService(cfg, "t1")
    try:
        req = PlanJobRequest(bin_type="box", bin_pose=PoseMsg.from_matrix(invert(_T_BIN_BASE)), seed_pct=4, whole=True)
        svc.run_job("t1-whole", req)
        st = svc.job_state("t1-whole")
        assert st.state == "done", st.reason
        [record] = list((tmp_path / "plans" / "box" / "whole").glob("*.json"))
        whole = read_document(record)
        assert whole["plan_id"] == st.plan_id and len(whole["stations"]) >= 2
        plans, _ = list_plans(tmp_path / "plans", "box", "external")
        ids = {s["plans"]["external"] for s in whole["stations"] if s["viewpoints"]["external"]}
        assert ids <= {p.plan_id for p in plans}
        assert all(p.job_id == "t1-whole" for p in plans if p.plan_id in ids)
        # the cycle at station k measures the bin from there: the lookup finds station k's plan
        for s in whole["stations"]:
            if not s["viewpoints"]["external"]:
                continue
            T_base_bin = invert(np.array(s["T_bin_base"]))
            reply = svc.on_lookup(PlanLookupRequest(bin_type="box", bin_pose=PoseMsg.from_matrix(T_base_bin)), None)
            assert reply.hit, reply.reason
            assert reply.plan_id == s["plans"]["external"]
            assert len(reply.viewpoints) == s["viewpoints"]["external"]
    finally:
        svc.close()
