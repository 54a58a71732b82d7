"""Cells, the planner pool and a PLC on separate hosts (network namespaces, one router each).

The short case runs in ``make test``: one cell host, the compute host with a one-worker pool,
the plant host with the PLC; the cell's replan job crosses the router hops to the pool and
the plan it made is found from the plant side. The big case (3 cells, 2 workers, link cut,
latency/loss through the relay, router restart) runs in ``make test-all``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.bench.reliability.cluster import bring_up, first_cycles, link_fault, records_check
from cellctl.bench.reliability.netns import PREFIX, _ip
from cellctl.planning.planfile import read_document
from tests.cluster.netns import cluster_of


@pytest.mark.timeout(900)  # a sim cell and a real planning job on 2 shared cores
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
@pytest.mark.timeout(2400)
def test_three_cells_pool_and_link_faults(tmp_path: Path) -> None:
    """3 cells (cell3 inspects another bin type), 2 workers; link cut, latency/loss, compute router restart."""
    kinds = ("case_study", "case_study", "tote")
    with cluster_of(tmp_path, cells=3, workers=2, relayed=("cell2",), bin_types=kinds) as cl:
        bring_up(cl)
        first = {r["cell"]: r for r in first_cycles(cl)}
        # cell1 plans; cell2 (same bin type, station pose and robot) finds cell1's plan; cell3 plans its own
        assert first["cell1"]["outcome"] == "replan_required"
        assert first["cell2"]["outcome"] == "completed"
        assert first["cell2"]["plan_id"] == first["cell1"]["job"]["plan_id"]
        assert first["cell3"]["outcome"] == "replan_required"
        lease = cl.opts.lease_ms / 1000
        # a cut link: the cycle aborts within the bound, or (the router mesh routed around it) completes
        res = link_fault(cl, "link_down", "cell1", lease, other="cell3")
        assert res["recovered"], res
        assert res["safe_state"] in ("Aborted", "Complete"), res
        if res["safe_state"] == "Aborted":
            assert res["detection_s"] <= lease + 1.0 and "planner" in res["reason"], res
        assert res["other_cell_job"]["state"] in ("running", "done"), res  # the pool kept serving cell3
        # the cell host cut off entirely: no path to the pool, Aborted within lease + 1 s by its own record
        res = link_fault(cl, "isolate", "cell1", lease)
        assert res["recovered"] and res["safe_state"] == "Aborted", res
        assert res["detection_s"] <= lease + 1.0 and "planner" in res["reason"], res
        res = link_fault(cl, "latency_loss", "cell2", lease)
        assert res["recovered"] and res["cycle_outcome"] == "completed", res
        res = link_fault(cl, "router_restart", "cell3", lease)
        assert res["recovered"] and res["safe_state"] == "Aborted", res
        assert res["detection_s"] <= lease + 1.0 and "planner" in res["reason"], res
        stats = cl.agents["cell1"].call("pool_stats")
        assert stats["planned_twice"] == 0 and stats["failed"] == 0
        for cell, rec in records_check(cl).items():
            assert rec["recorded_twice"] == 0 and not rec["seen_not_recorded"], (cell, rec)
            assert not rec["unfinished"] and not rec["logs_missing"], (cell, rec)
