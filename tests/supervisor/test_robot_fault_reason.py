"""A robot fault reaches the cycle's reason: the worker reports ``robot fault: <text>`` on its fault
key and withdraws its token; the CycleResult names the fault, whichever of the two arrives first."""

from __future__ import annotations

import time

import pytest

from cellctl.bus import keys
from cellctl.bus.codec import encode
from cellctl.messages import Event
from tests.fakes.workers import FakeCell
from tests.supervisor.test_cycle_over_zenoh import cell, plc  # noqa: F401 - the daemon and a PLC


def _wait(pred, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.02)


@pytest.mark.parametrize("report_first", [True, False], ids=["report-then-loss", "loss-then-report"])
def test_the_cycle_result_names_the_robot_fault(cfg, cell, plc, report_first) -> None:  # noqa: F811
    with FakeCell(cfg, n_viewpoints=20, move_delay_s=0.2) as fake:
        plc.cmd("reset")
        assert plc.wait_for(lambda s: s.state == "Idle", 10)
        assert plc.cmd("start").accepted
        _wait(lambda: "move" in fake.calls)
        pub = fake.session.declare_publisher(keys.worker_fault(cfg.cell_id, "robot"))
        report = encode(Event(level="error", text="robot fault: protective stop"))
        if report_first:
            pub.put(report)
            _wait(lambda: "robot" in cell.supervisor.health.faults)
            fake.kill("robot")
        else:
            fake.kill("robot")
            _wait(lambda: "robot" in cell.supervisor.health.lost)
            pub.put(report)
        st = plc.wait_for(lambda s: s.state == "Aborted", 10)
        assert st is not None
        res = plc.results.get(timeout=10)
        pub.undeclare()
    assert res.outcome == "failed"
    if report_first:  # the UR worker reports before it withdraws its token
        assert res.reason == "robot fault: protective stop (robot worker unavailable in Execute.scanning)"
    # a report after the loss still names the fault in the status (and in a cycle still open)
    _wait(lambda: cell.supervisor.status.last_error == "robot fault: protective stop (robot worker unavailable in "
          "Execute.scanning)")  # fmt: skip
    assert cell.supervisor.admin.stop_reason == cell.supervisor.status.last_error


def test_a_report_from_long_ago_is_not_the_reason_of_a_later_loss(cfg, cell, plc, monkeypatch) -> None:  # noqa: F811
    monkeypatch.setattr(cell.supervisor.health, "window_s", 0.2)
    with FakeCell(cfg, n_viewpoints=20, move_delay_s=0.2) as fake:
        plc.cmd("reset")
        assert plc.wait_for(lambda s: s.state == "Idle", 10)
        pub = fake.session.declare_publisher(keys.worker_fault(cfg.cell_id, "robot"))
        pub.put(encode(Event(level="error", text="robot fault: protective stop")))
        _wait(lambda: "robot" in cell.supervisor.health.faults)
        time.sleep(0.3)
        assert plc.cmd("start").accepted
        _wait(lambda: "move" in fake.calls)
        fake.kill("robot")
        assert plc.wait_for(lambda s: s.state == "Aborted", 10) is not None
        res = plc.results.get(timeout=10)
        pub.undeclare()
    assert res.reason is not None and res.reason.startswith("robot worker lost (liveliness token gone)")
