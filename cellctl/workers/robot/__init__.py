"""Robot worker: ``cellctl worker robot --backend sim|ur``.

Serves (``cell/<id>/robot/<op>``, request → reply):

* ``approach``: :class:`~cellctl.messages.ApproachRequest` → :class:`~cellctl.messages.ApproachReply`
* ``move``: :class:`~cellctl.messages.MoveRequest` → :class:`~cellctl.messages.MoveReply`
* ``state``: :class:`~cellctl.messages.RobotStateRequest` → :class:`~cellctl.messages.RobotState`
* ``wash``: :class:`~cellctl.messages.WashRequest` → :class:`~cellctl.messages.WashReply` (the nozzle's
  sweeps as continuous trajectories; stopped like a move)
* ``stop``: :class:`~cellctl.messages.StopRequest` → the same StopRequest (acknowledged)
* ur only: ``maintenance``: :class:`~cellctl.messages.RobotMaintenanceRequest` →
  :class:`~cellctl.messages.RobotMaintenanceReply` (an operator's explicit action; never automatic)
* twin only (sim, or ur against ``cellctl sim ur-controller``): ``scenario``:
  :class:`~cellctl.messages.SimScenarioRequest` → :class:`~cellctl.messages.SimState`,
  and ``cell/<id>/sim/state`` (queryable: :class:`~cellctl.messages.SimStateRequest` → SimState)

Publishes :class:`~cellctl.messages.JointState` on ``cell/<id>/robot/joints`` at
``robot.joint_state_hz`` and, for the sim, SimState on ``cell/<id>/sim/state`` on every change
(and at 1 Hz). Refusals (unreachable, collision, busy, bad input) are error replies; the
worker keeps serving.

Safety: a motion stops when the supervisor's liveliness token goes away (supervisor crashed,
or this worker lost its link to the router, e.g. after being frozen), so the arm never keeps
moving for a supervisor that can no longer stop it. A backend **fault** (ur: protective/emergency/
safeguard stop, reduced mode, lost RTDE) is published as a :class:`~cellctl.messages.FaultReport`
(condition, detail, robot and safety mode, safety bits) on ``cell/<id>/robot/fault`` (the
supervisor takes it as the reason) and then the worker
**withdraws its liveliness token** until an operator
clears it, so the supervisor holds or aborts the cycle by ``supervisor.on_worker_lost`` through
the same contract as a dead worker, while the worker keeps answering ``state`` and ``maintenance``.
"""

from __future__ import annotations

import logging
import threading
import time

import zenoh

from cellctl.bus import keys
from cellctl.bus.codec import encode
from cellctl.config import CellConfig
from cellctl.errors import ConfigError
from cellctl.geometry.robot_model import JOINT_NAMES
from cellctl.messages import (
    ApproachRequest,
    FaultReport,
    JointState,
    MoveRequest,
    RobotMaintenanceRequest,
    RobotStateRequest,
    SimScenarioRequest,
    SimStateRequest,
    StopRequest,
    WashRequest,
)
from cellctl.workers.robot._port import Robot

__all__ = ["BACKENDS", "Robot", "make_robot", "run_worker", "serve_robot"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

BACKENDS = ("sim", "ur")
FAULT_REPORT_LEAD_S = 0.01
"""How long a fault report goes ahead of the token's withdrawal (so the supervisor has the reason)."""


def make_robot(cfg: CellConfig, backend: str | None = None, **kwargs: object) -> Robot:
    """Build the robot backend named by ``backend`` (default ``cfg.robot.backend``).

    Raises:
        ConfigError: unknown backend or invalid sim configuration.
    """
    name = backend or cfg.robot.backend
    if name == "sim":
        from cellctl.workers.robot._sim import SimRobot

        return SimRobot(cfg, **kwargs)  # type: ignore[arg-type]
    if name == "ur":
        from cellctl.workers.robot.ur import UrRobot

        return UrRobot(cfg, **kwargs)  # type: ignore[arg-type]
    raise ConfigError(f"robot backend {name!r} is unknown; expected one of {list(BACKENDS)}")


def serve_robot(session, cfg: CellConfig, robot: Robot, stop: threading.Event) -> None:
    """Serve ``robot`` on ``session`` until ``stop`` is set (blocking)."""
    from cellctl.workers._server import WorkerServer

    cell = cfg.cell_id
    changed = threading.Event()
    twin = bool(getattr(robot, "publishes_twin", False))
    if hasattr(robot, "on_change"):
        robot.on_change = changed.set  # type: ignore[attr-defined]

    def _stop(req: StopRequest, _raw: bytes | None) -> StopRequest:
        robot.stop(req.reason)
        return req

    def _supervisor_seen(sample) -> None:  # zenoh.Sample; runs on a Zenoh thread
        if sample.kind == zenoh.SampleKind.DELETE:
            robot.stop("supervisor lost (liveliness token gone)")  # sets an event: never blocks

    # history: a token declared before this subscriber must still report its DELETE
    sup_watch = session.liveliness().declare_subscriber(keys.alive(cell, "supervisor"), _supervisor_seen, history=True)
    pub_j = session.declare_publisher(keys.robot_joints(cell))
    pub_s = session.declare_publisher(keys.sim_state(cell)) if twin else None
    pub_e = session.declare_publisher(keys.worker_fault(cell, "robot"), express=True)
    with WorkerServer(session, cell, "robot") as server:

        def _fault(report: FaultReport) -> None:  # monitor thread, not a Zenoh callback
            pub_e.put(encode(report))
            if report.active:
                # the report first: the supervisor names it as the reason of the token's loss. An
                # undeclaration sent at once overtakes a put (38 of 40 times on loopback); after a few
                # ms it never did. The arm is already stopped or stopping (stopJ went before).
                time.sleep(FAULT_REPORT_LEAD_S)
                server.withdraw()  # the supervisor holds/aborts as for a lost worker
            else:
                server.announce()

        if hasattr(robot, "on_fault"):
            robot.on_fault = _fault  # type: ignore[attr-defined]
            if getattr(robot, "fault_report", None) is not None:
                _fault(robot.fault_report)  # type: ignore[attr-defined]
        server.serve("approach", ApproachRequest, lambda r, _: robot.approach(r))
        server.serve("move", MoveRequest, lambda r, _: robot.move(r))
        server.serve("wash", WashRequest, lambda r, _: robot.wash(r))
        server.serve("state", RobotStateRequest, lambda r, _: robot.state())
        server.serve("stop", StopRequest, _stop)
        if hasattr(robot, "maintenance"):
            server.serve("maintenance", RobotMaintenanceRequest, lambda r, _: robot.maintenance(r))  # type: ignore[attr-defined]
        if twin:
            server.serve("scenario", SimScenarioRequest, lambda r, _: robot.set_scenario(r))
            server.serve("sim_state", SimStateRequest, lambda r, _: robot.sim_state(r.washes), key=keys.sim_state(cell))
        if getattr(robot, "fault", None) is None:
            server.announce()
        log.info("robot worker serving cell %s", cell)
        period = 1.0 / cfg.robot.joint_state_hz
        last_sim = 0.0
        try:
            while not stop.is_set():
                st = robot.state()
                pub_j.put(encode(JointState(names=list(JOINT_NAMES), position=st.joints)))
                now = time.monotonic()
                if pub_s is not None and (changed.is_set() or now - last_sim > 1.0):
                    changed.clear()
                    pub_s.put(encode(robot.sim_state()))  # type: ignore[attr-defined]
                    last_sim = now
                stop.wait(period)
        finally:
            robot.stop("worker shutting down")
            sup_watch.undeclare()
            pub_j.undeclare()
            pub_e.undeclare()
            if pub_s is not None:
                pub_s.undeclare()


def run_worker(cfg: CellConfig, backend: str | None, stop: threading.Event) -> None:
    """Entry point of ``cellctl worker robot``: build the backend, serve until ``stop``."""
    from cellctl.bus.session import open_session

    robot = make_robot(cfg, backend)
    session = open_session(cfg, "client")
    try:
        with robot:
            serve_robot(session, cfg, robot, stop)
    finally:
        session.close()
