"""`cellctl run --with-workers` as a new user runs it (the shipped config, the sim workers as child
processes), Reset, Start: the cycle is a whole-bin cycle over every station and both surfaces, and its
verdict is gated on each surface's seen share (issue 35). Slow: a whole-bin plan and cycle in the twin."""

from __future__ import annotations

import pytest

from cellctl.bench.options import BenchOptions
from cellctl.bus.session import private_bus_overrides

pytestmark = [pytest.mark.slow, pytest.mark.timeout(2400)]  # a whole-bin plan and cycle on 2 shared cores

# motion and frames only (not FAST_SIM, which pins single-station cycles for the controller benches)
QUICK = [
    "robot.settle_s=0",
    "robot.speed_scale=1000",
    "robot.plan_timeout_s=1.0",
    "camera.width=640",
    "camera.height=360",
    "planner.seed_pct=3",
]


def test_the_shipped_config_runs_a_whole_bin_cycle_in_the_twin() -> None:
    from cellctl.bench.reliability.sim_cell import running_sim_cell

    opts = BenchOptions(overrides=(*private_bus_overrides(), *QUICK))
    with running_sim_cell(opts, "whole-default", []) as run:
        assert run.cfg.planner.whole.enabled
        for _ in range(3):  # a station parked beyond its plan's tolerance replans that station, then again
            run.plc.to_idle()
            res = run.plc.run_cycle(900)
            assert res.stations, f"not a whole-bin cycle: {res.outcome.value} {res.reason}"
            if res.outcome.value != "replan_required" or not res.planner_job_id:
                break
            run.plc.wait_plan_job(res.planner_job_id, 900)
    assert res.outcome.value == "completed", res.reason
    assert res.whole_plan_id is not None and len(res.stations) >= 2
    # both surfaces scanned (the result on the wire may keep only its telling views: fit_to_wire; the
    # seen shares come from every view)
    assert set(res.coverage_by_surface) == {"external", "internal"}
    seen, need = res.coverage_by_surface, res.min_seen_fraction
    assert need == {"external": 0.6, "internal": 0.6} and all(0 < f <= 1 for f in seen.values())
    short = [s for s in seen if seen[s] < need[s]]
    # a clean twin bin: clean when both surfaces were seen enough, else incomplete, never dirty
    assert res.verdict == ("incomplete" if short else "clean"), (res.verdict, seen, res.reason)
    print(f"whole-bin cycle in the twin: {len(res.stations)} stations, seen {seen}, verdict {res.verdict}")
