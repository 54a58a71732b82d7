"""The secured bus and the UR robot's operator path: who may call ``robot/maintenance``, and that a
worker's fault report reaches the supervisor (and observers) under the generated ACL."""

from __future__ import annotations

import time

from cellctl.bus import keys
from cellctl.bus.codec import encode
from cellctl.bus.session import open_session
from cellctl.messages import Event
from tests.bus.test_access_control import cell, deployment, secured  # noqa: F401 - router + principals

C = "cell1"


def test_only_people_may_call_the_robots_maintenance_op(cell, secured) -> None:  # noqa: F811
    with open_session(secured("robot"), "client") as rob:
        rob.declare_queryable(keys.robot_op(C, "maintenance"), lambda q: q.reply(q.key_expr, b"unlocked"))
        rob.declare_queryable(keys.robot_op(C, "move"), lambda q: q.reply(q.key_expr, b"moved"))
        time.sleep(0.3)
        for who in ("operator", "hmi", "engineer"):
            with open_session(secured(who), "client") as s:
                (reply,) = s.get(keys.robot_op(C, "maintenance"), timeout=2)
                assert reply.ok.payload.to_bytes() == b"unlocked", who
        for who in ("plc", "viewer", "camera", "planner"):
            with open_session(secured(who), "client") as s:
                assert list(s.get(keys.robot_op(C, "maintenance"), timeout=1)) == [], who
        for who in ("operator", "hmi"):  # exactly that op: no motion
            with open_session(secured(who), "client") as s:
                assert list(s.get(keys.robot_op(C, "move"), timeout=1)) == [], who


def test_a_robot_fault_report_reaches_the_supervisor_and_observers(cell, secured) -> None:  # noqa: F811
    seen: list[bytes] = []
    with open_session(secured("operator"), "client") as op, open_session(secured("robot"), "client") as rob:
        op.declare_subscriber(keys.worker_fault(C, "robot"), lambda s: seen.append(s.payload.to_bytes()))
        pub = rob.declare_publisher(keys.worker_fault(C, "robot"))
        time.sleep(0.3)
        pub.put(encode(Event(level="error", text="robot fault: protective stop")))
        deadline = time.monotonic() + 5
        while "robot" not in cell.supervisor.health.faults or not seen:
            assert time.monotonic() < deadline, "the fault report did not arrive"
            time.sleep(0.02)
    assert cell.supervisor.health.faults["robot"][1] == "robot fault: protective stop"
    assert b"protective stop" in seen[0]
