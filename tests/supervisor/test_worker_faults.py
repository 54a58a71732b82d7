"""Worker processes killed (SIGKILL) or frozen (SIGSTOP) at each cycle step (issue 8, item 1).

The daemon runs in this process; each worker double is its own process, so the signals are
real. Each op of a double takes a little time, so that every step lasts long enough to be hit
from a Status. The default suite runs one case per worker and fault kind; ``make test-all``
runs every worker × fault × step.
"""

from __future__ import annotations

import subprocess

import pytest

from cellctl.app import build_cell
from cellctl.bench.reliability.faults import FAULTS, FaultCase, FaultInjector
from cellctl.bus.plc_client import PlcClient
from cellctl.config import load_config
from tests.conftest import cfg_overrides, free_port
from tests.fakes.worker_process import spawn
from tests.fakes.workers import fake_identify

ROLES = ("robot", "camera", "classifier", "planner")
STEPS = ("approaching", "identifying", "checking_cache", "replanning", "scanning", "classifying")
DELAYS = {"approach": 0.4, "move": 0.15, "capture": 0.05, "classify": 0.3, "lookup": 0.4, "jobs": 0.4}


class DoubleWorkers:
    """The four worker doubles as processes; the planner misses every lookup when ``miss``."""

    def __init__(self, overrides: list[str]) -> None:
        self.overrides = overrides
        self.miss = False
        self.procs = {r: spawn(r, overrides, DELAYS) for r in ROLES}

    def pid(self, role: str) -> int:
        return self.procs[role].pid

    def restart(self, role: str) -> None:
        self.procs[role].wait(10)
        self.procs[role] = spawn(role, self.overrides, DELAYS, miss=self.miss and role == "planner")

    def set_planner_miss(self, miss: bool) -> bool:
        """Restart the planner double if its mode changes; True when it did."""
        if miss == self.miss:
            return False
        self.miss = miss
        self.procs["planner"].kill()
        self.restart("planner")
        return True

    def close(self) -> None:
        for p in self.procs.values():
            p.terminate()
        for p in self.procs.values():
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("faults")
    # a 1 s lease keeps the frozen cases short; the bound scales with it
    overrides = [*cfg_overrides(tmp, free_port()), "bus.lease_ms=1000"]
    cfg = load_config(None, overrides)
    from cellctl.geometry.catalog import load_catalog

    cell = build_cell(cfg, identification=(fake_identify, load_catalog(cfg.path(cfg.catalog))))
    workers = DoubleWorkers(overrides)
    plc = PlcClient(cfg, "faults-test")
    inj = FaultInjector(cfg, plc, workers, cycle_timeout=30, good_outcomes=("completed", "replan_required"))
    try:
        assert plc.wait_workers(ROLES, 60), f"worker doubles did not come up: {plc.last_status}"
        yield cfg, cell, workers, inj
    finally:
        inj.close()
        plc.close()
        workers.close()
        cell.close()


def _check(rig, case: FaultCase):
    cfg, cell, workers, inj = rig
    if workers.set_planner_miss(case.step == "replanning"):
        inj.plc.wait_for(lambda s: not s.workers.get("planner"), 5)
        assert inj.plc.wait_workers(ROLES, 60)
    rep = inj.run(case)
    print(rep.as_dict())  # shown with -s: the detection times of this run
    assert rep.injected_in == f"Execute.{case.step}", rep.problems
    assert rep.ok, f"{case.name}: {rep.problems}"
    if rep.safe_state == "Complete":
        # the worker was not needed any more and the cycle ended before one lease: a good record
        assert case.fault == "freeze" and case.step in ("replanning", "classifying"), rep
        assert rep.outcome in ("completed", "replan_required")
    else:
        assert rep.safe_state == "Aborted"
        assert rep.outcome == "failed" and case.role in rep.reason
    assert rep.motion_requests_after_detection == 0
    assert rep.detection_s is not None and rep.detection_s <= inj.detect_bound_s[case.fault]
    assert rep.recovery_outcome in ("completed", "replan_required")
    return rep


@pytest.mark.parametrize(
    "case",
    [
        FaultCase("robot", "kill", "scanning"),
        FaultCase("robot", "freeze", "approaching"),
        FaultCase("camera", "kill", "identifying"),
        FaultCase("classifier", "freeze", "classifying"),
        FaultCase("planner", "kill", "checking_cache"),
        FaultCase("planner", "freeze", "replanning"),
    ],
    ids=lambda c: c.name.replace(" ", "-"),
)
def test_worker_fault_is_detected_made_safe_recorded_and_recovered(rig, case: FaultCase) -> None:
    rep = _check(rig, case)
    if case.fault == "kill":
        assert rep.detection_s < 1.0  # the token goes with the process
    else:
        assert rep.detection_s >= 0.5  # a frozen process is noticed by its lease, not sooner


@pytest.mark.slow
@pytest.mark.parametrize("step", STEPS)
@pytest.mark.parametrize("fault", list(FAULTS))
@pytest.mark.parametrize("role", ROLES)
def test_every_worker_fault_at_every_step(rig, role: str, fault: str, step: str) -> None:
    _check(rig, FaultCase(role, fault, step))
