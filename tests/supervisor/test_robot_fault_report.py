"""The typed fault report (:class:`~cellctl.messages.FaultReport`) on ``cell/<id>/robot/fault``: it
names the reason of the robot token's loss, lands in the cycle's log, and when it trails the loss
the cycle's close waits for it; a report later than that corrects what is not sealed."""

from __future__ import annotations

import time

import pytest

from cellctl.bus import keys
from cellctl.bus.codec import decode, encode
from cellctl.messages import FaultReport
from cellctl.recording.replay import read_cycle
from tests.fakes.workers import FakeCell
from tests.supervisor.test_cycle_over_zenoh import cell, plc  # noqa: F401 - the daemon and a PLC

REPORT = FaultReport(
    role="robot",
    condition="protective_stop",
    detail="protective stop",
    robot_mode="RUNNING",
    safety_mode="PROTECTIVE_STOP",
    safety_status_bits=(1 << 2) | (1 << 10),
    safety_flags=["protective_stopped", "stopped_due_to_safety"],
)
REASON = "robot fault: protective stop (robot worker unavailable in Execute.scanning)"


def _wait(pred, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.01)


def _fault_in_a_scan(cfg, cell, plc, fake, report_first: bool, lag_s: float = 0.0, send: bool = True):  # noqa: F811
    """Start a cycle, lose the robot in a scan (its report before or ``lag_s`` after the loss, or none)."""
    pub = fake.session.declare_publisher(keys.worker_fault(cfg.cell_id, "robot"))
    plc.cmd("reset")
    assert plc.wait_for(lambda s: s.state == "Idle", 10)
    assert plc.cmd("start").accepted
    _wait(lambda: "move" in fake.calls)
    if send and report_first:
        pub.put(encode(REPORT))
        _wait(lambda: "robot" in cell.supervisor.health.faults)
    fake.kill("robot")
    if send and not report_first:
        _wait(lambda: "robot" in cell.supervisor.health.lost)
        time.sleep(lag_s)
        pub.put(encode(REPORT))
    assert plc.wait_for(lambda s: s.state == "Aborted", 10) is not None
    res = plc.results.get(timeout=10)
    return res, pub


def test_a_typed_report_names_the_fault_and_is_in_the_cycle_log(cfg, cell, plc) -> None:  # noqa: F811
    with FakeCell(cfg, n_viewpoints=20, move_delay_s=0.2) as fake:
        res, pub = _fault_in_a_scan(cfg, cell, plc, fake, report_first=True)
        pub.undeclare()
    assert res.outcome == "failed" and res.reason == REASON
    got = cell.supervisor.health.fault_reports["robot"]
    assert got.condition == "protective_stop" and got.safety_mode == "PROTECTIVE_STOP"
    logged = [decode(m.data) for m in read_cycle(cfg.path(res.log)).on(keys.worker_fault(cfg.cell_id, "robot"))]
    assert logged == [REPORT]


def test_a_report_just_behind_the_loss_still_names_the_fault_in_the_sealed_result(cfg, cell, plc) -> None:  # noqa: F811
    with FakeCell(cfg, n_viewpoints=20, move_delay_s=0.2) as fake:
        res, pub = _fault_in_a_scan(cfg, cell, plc, fake, report_first=False, lag_s=0.05)
        pub.undeclare()
    # the published result and the index row (sealed at the close) both carry it
    assert res.reason == REASON
    assert cell.supervisor.index.get(res.cycle_id).reason == REASON


def test_a_report_after_the_close_corrects_what_is_not_sealed(cfg, cell, plc, monkeypatch) -> None:  # noqa: F811
    import cellctl.supervisor.cycles as cycles

    monkeypatch.setattr(cycles, "REASON_GRACE_S", 0.0)
    with FakeCell(cfg, n_viewpoints=20, move_delay_s=0.2) as fake:
        res, pub = _fault_in_a_scan(cfg, cell, plc, fake, report_first=False, lag_s=0.3)
        _wait(lambda: cell.supervisor.status.last_error == REASON)
        pub.undeclare()
    lost = "robot worker lost (liveliness token gone) in Execute.scanning"
    assert res.reason == lost  # published at the close
    assert cell.supervisor.index.get(res.cycle_id).reason == lost  # sealed: hash-chained, never re-closed
    kept = [r for r in cell.supervisor.results if r.cycle_id == res.cycle_id]
    assert [r.reason for r in kept] == [REASON]
    assert cell.supervisor.admin.stop_reason == REASON


def test_a_cleared_report_is_no_reason_for_a_later_loss(cfg, cell, plc) -> None:  # noqa: F811
    with FakeCell(cfg, n_viewpoints=20, move_delay_s=0.2) as fake:
        pub = fake.session.declare_publisher(keys.worker_fault(cfg.cell_id, "robot"))
        time.sleep(0.1)
        pub.put(encode(REPORT))
        _wait(lambda: "robot" in cell.supervisor.health.faults)
        pub.put(encode(REPORT.model_copy(update={"active": False, "detail": "cleared by maintenance"})))
        _wait(lambda: "robot" not in cell.supervisor.health.faults)
        res, pub2 = _fault_in_a_scan(cfg, cell, plc, fake, report_first=False, send=False)
        pub.undeclare()
        pub2.undeclare()
    assert res.reason is not None and res.reason.startswith("robot worker lost (liveliness token gone)")


@pytest.mark.parametrize(
    ("field", "value"), [("condition", "tea_break"), ("detail", ""), ("role", "Robot!"), ("safety_status_bits", -1)]
)
def test_a_bad_report_is_refused_naming_the_field(field: str, value: object) -> None:
    import json

    from cellctl.errors import ProtocolError

    bad = REPORT.model_dump(mode="json") | {field: value}
    with pytest.raises(ProtocolError, match=field):
        decode(json.dumps(bad).encode())
