"""Cells, the planner pool and a PLC on separate hosts (network namespaces, one router each).

The short case runs in ``make test``: one cell host, the compute host with a one-worker pool,
the plant host with the PLC; the cell's replan job crosses the router hops to the pool and
the plan it made is found from the plant side. The big case (3 cells, 2 workers, link cut,
latency/loss through the relay, router restart) runs in ``make test-all``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.planning.planfile import read_document
from cellctl.reliability.cluster import bring_up, first_cycles, link_fault, records_check
from cellctl.reliability.netns import PREFIX, _ip
from tests.cluster.netns import cluster_of


def test_replan_job_crosses_the_router_hop(tmp_path: Path) -> None:
    with cluster_of(tmp_path, cells=1, workers=1) as cl:
        bring_up(cl)
        (first,) = first_cycles(cl)
        assert first["outcome"] == "replan_required", first
        assert first["planner_job_id"].startswith("cell1-"), first  # the pool's queue named it
        assert first["job"]["state"] == "done", first
        stats = cl.agents["cell1"].call("pool_stats")
        assert (stats["submitted"], stats["planned"], stats["planned_twice"]) == (1, 1, 0)
        (worker,) = stats["per_worker"]
        assert f"pool worker {worker}" in cl.plant.log_of("compute", "planner0")  # planned on the compute host
        # the plan is found across the hops (plant -> cell1 -> compute) at the bin pose the cell measured
        rec = read_document(cl.jobs_dir / f"{first['planner_job_id']}.json")
        found = cl.agents["cell1"].call("lookup", bin_type="case_study", pose=rec["request"]["bin_pose"])
        assert found["hit"] and found["plan_id"] == first["job"]["plan_id"], found
        rows = cl.index_rows("cell1")
        assert [r["outcome"] for r in rows] == ["replan_required"]
        namespaces = [n for n in _ip("netns", "list").stdout.split() if n.startswith(PREFIX)]
        assert len(namespaces) == 3
    assert not [n for n in _ip("netns", "list").stdout.split() if n.startswith(cl.plant.tag)]


@pytest.mark.slow
def test_three_cells_pool_and_link_faults(tmp_path: Path) -> None:
    """3 cells (cell3 at another station), 2 workers; link cut, latency/loss, compute router restart."""
    with cluster_of(tmp_path, cells=3, workers=2, relayed=("cell2",), station_offsets_m=(0.0, 0.0, 0.3)) as cl:
        bring_up(cl)
        first = {r["cell"]: r for r in first_cycles(cl)}
        # cell1 plans; cell2 (same station pose, same robot) finds cell1's plan; cell3 (0.3 m away) plans its own
        assert first["cell1"]["outcome"] == "replan_required"
        assert first["cell2"]["outcome"] == "completed"
        assert first["cell2"]["plan_id"] == first["cell1"]["job"]["plan_id"]
        assert first["cell3"]["outcome"] == "replan_required"
        lease = cl.opts.lease_ms / 1000
        for case, cell in (("link_down", "cell1"), ("latency_loss", "cell2"), ("router_restart", "cell3")):
            res = link_fault(cl, case, cell, lease)
            assert res["recovered"], res
            if case != "latency_loss":
                assert res["safe_state"] == "Aborted", res
                assert res["detection_s"] <= lease + 1.0, res
                assert "planner" in res["reason"], res
            else:
                assert res["cycle_outcome"] == "completed", res
        stats = cl.agents["cell1"].call("pool_stats")
        assert stats["planned_twice"] == 0 and stats["failed"] == 0
        for cell, rec in records_check(cl).items():
            assert rec["recorded_twice"] == 0 and not rec["seen_not_recorded"], (cell, rec)
            assert not rec["unfinished"] and not rec["logs_missing"], (cell, rec)
