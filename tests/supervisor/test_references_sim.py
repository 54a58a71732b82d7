"""Commission, then judge against the references, in the twin over real Zenoh (issue 34, item 2).

The sim cell as ``cellctl run --with-workers`` runs it (robot, camera, the real classifier worker,
planner; single station for time): a commissioning cycle in maintenance stores a reference per
viewpoint and enrolls the detector; the next clean cycle of the same plan sends each view with its
reference and the classifier worker decides it with the comparison (``decision_path`` references,
per view ``decided_by``); a bin parked beyond the plan's tolerance gets a new plan, which no set
holds: its views are judged by the detector alone and the result says so. Slow: two plans, an
enrollment and four cycles in the twin.
"""

from __future__ import annotations

import math

import pytest

from cellctl.bench.options import BenchOptions
from cellctl.bench.reliability.sim_cell import FAST_SIM
from cellctl.bus import keys
from cellctl.bus.rpc import request
from cellctl.bus.session import private_bus_overrides
from cellctl.messages import Command, SimScenarioRequest, SimState, now_iso

pytestmark = [pytest.mark.slow, pytest.mark.timeout(3600)]

USER = "hmi:commissioner"


def _commission(plc, timeout: float):
    plc.to_idle()
    ack = plc.unit_mode("maintenance", user=USER)
    assert ack.accepted, ack.reason
    plc.drain()
    cmd = Command(command="start", user=USER, params={"mode": "commission"}, request_id=plc.next_id(), stamp=now_iso())
    ack = plc.send(cmd)
    assert ack.accepted, ack.reason
    res = plc.results.get(timeout=timeout)
    plc.wait_for(lambda s: s.state in ("Complete", "Aborted", "Stopped"), 30)
    plc.to_idle()
    assert plc.unit_mode("production", user=USER).accepted
    return res


def test_commissioned_plan_is_judged_against_its_references_and_a_replan_falls_back() -> None:
    from cellctl.bench.reliability.sim_cell import running_sim_cell

    opts = BenchOptions(overrides=tuple(private_bus_overrides()))
    with running_sim_cell(opts, "references-sim", FAST_SIM) as run:
        plc = run.plc
        comm = _commission(plc, 1800)
        assert comm.outcome.value == "completed", comm.reason
        assert comm.commission is not None and comm.commission.references > 0
        plc.to_idle()
        clean = plc.run_cycle(900)
        assert clean.outcome.value == "completed", clean.reason
        surface = next(iter(clean.decision_path))
        assert clean.decision_path == {surface: "references"}, [
            (v.decided_by, v.reference_reason) for v in clean.viewpoints
        ]
        assert clean.reference_version == comm.commission.version
        judged = [v for v in clean.viewpoints if v.label is not None and v.relook_of is None]
        by_ref = [v for v in judged if v.decided_by == "reference"]
        assert by_ref and all(v.reference_reason == "aligned" for v in by_ref)
        # views the comparison did not decide say why (a rejected alignment), never silently
        assert all(v.reference_reason is not None for v in judged if v.decided_by != "reference")
        print(f"clean cycle: {len(by_ref)}/{len(judged)} views decided against their references, {clean.verdict}")
        # the bin parked far off: beyond the plan's tolerance -> a new plan, which no set holds
        far = SimScenarioRequest(park_offset_xy_yaw=(-0.15, 0.0, math.radians(5.0)))
        request(plc.session, keys.robot_op(run.cfg.cell_id, "scenario"), far, SimState, timeout=30, role="robot")
        plc.to_idle()
        res = plc.run_cycle(900)
        assert res.outcome.value == "replan_required" and res.planner_job_id, res.reason
        end = plc.wait_plan_job(res.planner_job_id, 1800)
        assert end is not None and end.state == "done"
        plc.to_idle()
        replanned = plc.run_cycle(900)
    assert replanned.outcome.value == "completed", replanned.reason
    assert replanned.plan_id != clean.plan_id
    enrolled = bool(comm.commission.enrolled)
    assert replanned.decision_path == {surface: "enrolled" if enrolled else "shipped"}
    assert replanned.reference_version is None
    assert all(v.decided_by != "reference" and v.reference_reason is None for v in replanned.viewpoints)
