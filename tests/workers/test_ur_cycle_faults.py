"""Faults of the UR10e during a cycle: the daemon, the real UR robot worker (ur-rtde) against the
emulated controller, and doubles for camera, classifier and planner, all over Zenoh on loopback.

Each injected fault (protective stop, emergency stop, safeguard stop, a dropped link, a stalled
controller) at each motion (the approach's arm motion, a scanning move) must leave the arm
stopped, the cycle recorded as failed with the fault in its reason, and, after the operator's
recovery (the ``robot/maintenance`` op), a good cycle. The default suite runs one case; the
matrix is ``slow``. Waits are bounded polls on the controller's and the supervisor's own state.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest

from cellctl.app import build_cell
from cellctl.bus import keys
from cellctl.bus.plc_client import PlcClient
from cellctl.bus.rpc import request
from cellctl.bus.session import open_session
from cellctl.config import load_config
from cellctl.messages import (
    PlanLookupReply,
    PlanLookupRequest,
    PlannedViewpoint,
    RobotMaintenanceReply,
    RobotMaintenanceRequest,
)
from cellctl.sim import scene
from cellctl.sim.ur_controller import EmulatorProcess, free_loopback_host
from cellctl.workers.robot import make_robot, serve_robot
from tests.conftest import cfg_overrides
from tests.fakes.workers import CAM_POSE, FakeCell, fake_identify

pytestmark = pytest.mark.timeout(300, method="thread")  # ur-rtde's calls may block in C++

N_VIEWPOINTS = 3


@pytest.fixture(scope="module")
def emu(tmp_path_factory):
    with EmulatorProcess(
        free_loopback_host(),
        ["sim.ur_controller.unlock_delay_s=0.3"],
        log_path=tmp_path_factory.mktemp("emu") / "ur-controller.log",
        verbose=2,  # every command the control script ran, for a failure's story
    ) as e:
        yield e


@dataclass
class ReachablePlan(FakeCell):
    """Camera, classifier and planner doubles; the plan's viewpoints are wrist motions near home."""

    def _lookup(self, req: PlanLookupRequest, _: bytes | None) -> PlanLookupReply:
        self._guard("lookup")
        vps = []
        for i in range(N_VIEWPOINTS):
            q = scene.HOME_JOINTS + np.array([0.0, 0.0, 0.0, 0.15 * (i % 2), 0.0, 0.6 * (1 if i % 2 else -1)])
            vps.append(PlannedViewpoint(index=i, camera_pose=CAM_POSE, joints=q.tolist(), faces=[2 * i, 2 * i + 1]))
        return PlanLookupReply(hit=True, plan_id="plan-ur", viewpoints=vps, coverage=0.9, mesh_faces=10)


class RobotWorker:
    """``cellctl worker robot`` with ``robot.backend: ur``, in a thread of this process."""

    def __init__(self, cfg) -> None:
        self.robot = make_robot(cfg)
        self.session = open_session(cfg, "client")
        self.stop = threading.Event()
        self.thread = threading.Thread(
            target=serve_robot, args=(self.session, cfg, self.robot, self.stop), name="robot-worker", daemon=True
        )
        self.thread.start()

    def close(self) -> None:
        self.stop.set()
        self.thread.join(20)
        self.robot.close()
        self.session.close()


@pytest.fixture
def rig(emu, tmp_path, port):
    from cellctl.geometry.catalog import load_catalog

    emu.inject("reset")
    cfg = load_config(
        None,
        [
            *cfg_overrides(tmp_path, port),
            "robot.backend=ur",
            f"robot.ur.host={emu.host}",
            "robot.speed_fraction=0.5",
            "robot.speed_scale=20",  # the twin base parks in 0.2 s
            "robot.ur.connect_attempts=3",
            "robot.ur.faults.data_stale_ms=1000",  # a Python emulator on a loaded machine sends late now and then
            "robot.ur.faults.watchdog_hz=2",
        ],
    )
    cell = build_cell(cfg, identification=(fake_identify, load_catalog(cfg.path(cfg.catalog))))
    fakes = ReachablePlan(cfg, roles=("camera", "classifier", "planner")).start()
    worker = RobotWorker(cfg)
    plc = PlcClient(cfg, "test")
    try:
        assert plc.wait_workers(("robot", "camera", "classifier", "planner"), 30)
        yield Rig(cfg, cell, plc, worker, emu)
    finally:
        plc.close()
        worker.close()
        fakes.close()
        cell.close()
        emu.inject("reset")


@dataclass
class Rig:
    cfg: object
    cell: object
    plc: PlcClient
    worker: RobotWorker
    emu: EmulatorProcess

    def state(self) -> str:
        return self.cell.supervisor.state  # type: ignore[attr-defined]

    def wait(self, pred: Callable[[], bool], what: str, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not pred():
            assert time.monotonic() < deadline, f"{what} not reached within {timeout_s:g} s (state {self.state()})"
            time.sleep(0.01)

    def start_cycle(self) -> None:
        if self.plc.command("reset", timeout=10).accepted:
            self.wait(lambda: self.state() == "Idle", "Idle")
        assert self.plc.command("start", timeout=10).accepted

    def maintenance(self, action: str) -> RobotMaintenanceReply:
        reply, _ = request(
            self.plc.session,
            keys.robot_op(self.cfg.cell_id, "maintenance"),  # type: ignore[attr-defined]
            RobotMaintenanceRequest(action=action, user="operator"),
            RobotMaintenanceReply,
            timeout=30,
            role="robot",
        )
        return reply


# fault -> (injection, the fault texts the reason may carry (one of), the operator's recovery)
RECOVERY: dict[str, tuple[str, tuple[str, ...], Callable[[Rig], None]]] = {
    "protective_stop": (
        "protective_stop injected",
        ("protective stop",),
        lambda r: (time.sleep(0.4), r.maintenance("unlock_protective_stop")),
    ),
    "estop": (
        "estop",
        ("emergency stop",),
        lambda r: (r.emu.inject("estop_release"), r.maintenance("power_on"), r.maintenance("brake_release")),
    ),
    "safeguard": ("safeguard", ("safeguard stop",), lambda r: r.emu.inject("safeguard_reset")),
    "drop": ("drop 0.5", ("lost RTDE connection",), lambda r: time.sleep(0.7)),
    # a frozen controller: no data, a control call that does not return (the client cannot tell), or, when
    # the controller resumes before either is noticed, its RTDE watchdog (2 Hz here) expired and stopped the program
    "stall": (
        "stall 1.5",
        ("no RTDE data", "lost RTDE connection", "control program stopped during a motion"),
        lambda r: time.sleep(0.7),
    ),
}
MOTIONS = ("approaching", "scanning")
CONDITIONS = {  # fault -> the typed report's condition (FaultReport.condition), one of
    "protective_stop": ("protective_stop",),
    "estop": ("emergency_stop",),
    "safeguard": ("safeguard_stop",),
    "drop": ("lost_connection",),
    "stall": ("stall", "lost_connection", "program_stopped"),
}


def _fault_cycle_then_good_cycle(rig: Rig, fault: str, motion: str) -> None:
    inject, texts, recover = RECOVERY[fault]
    results = rig.plc.results
    rig.start_cycle()
    rig.wait(lambda: rig.state() == f"Execute.{motion}" and rig.emu.state()["moving"], f"{motion} motion")
    rig.emu.inject(inject)
    rig.wait(lambda: rig.state() == "Aborted", "Aborted")
    res = results.get(timeout=30)
    assert res.outcome == "failed"
    # the token's loss ("robot fault: … (robot worker unavailable in Execute.<step>)") or, when the
    # step's failed request came first, its error ("… UR fault (…) …"): the fault's text either way
    assert res.reason is not None and any(t in res.reason for t in texts), res.reason
    if res.reason.startswith("robot fault: "):
        assert f"in Execute.{motion}" in res.reason
    # the arm stopped where it was and stays there
    rig.wait(lambda: not rig.emu.state()["moving"], "arm at rest", 10)
    q = np.array(rig.emu.state()["q"])
    time.sleep(0.5)
    assert np.abs(np.array(rig.emu.state()["q"]) - q).max() < 1e-9
    assert rig.worker.robot.fault is not None and any(t in rig.worker.robot.fault for t in texts)
    # the typed report reached the supervisor (FaultReport on robot/fault), with the controller's state
    rig.wait(lambda: "robot" in rig.cell.supervisor.health.fault_reports, "the fault report", 10)
    report = rig.cell.supervisor.health.fault_reports["robot"]
    assert report.condition in CONDITIONS[fault] and report.detail == rig.worker.robot.fault
    assert report.robot_mode is not None and report.safety_status_bits is not None
    # the operator's recovery: the condition cleared at the controller, then clear_fault
    recover(rig)
    assert rig.maintenance("clear_fault").fault is None
    rig.wait(lambda: rig.cell.supervisor.status.workers.get("robot", False), "robot worker back", 30)
    rig.wait(lambda: "robot" not in rig.cell.supervisor.health.fault_reports, "the cleared report", 10)
    assert rig.plc.command("clear", timeout=10).accepted
    rig.wait(lambda: rig.state() == "Stopped", "Stopped")
    rig.start_cycle()
    rig.wait(lambda: rig.state() == "Complete", "Complete", 120)
    good = results.get(timeout=30)
    assert good.outcome == "completed", good.reason
    assert len(good.viewpoints) == N_VIEWPOINTS and all(v.error is None for v in good.viewpoints)


def test_a_protective_stop_in_a_scanning_move_fails_the_cycle_and_the_operator_recovers(rig) -> None:
    _fault_cycle_then_good_cycle(rig, "protective_stop", "scanning")


@pytest.mark.slow  # two cycles with the UR worker per case (≈ 18 s each on a loaded machine)
@pytest.mark.parametrize(
    ("fault", "motion"),
    [(f, m) for f in sorted(RECOVERY) for m in MOTIONS if (f, m) != ("protective_stop", "scanning")],  # default's
)
def test_every_fault_at_every_motion(rig, fault: str, motion: str) -> None:
    _fault_cycle_then_good_cycle(rig, fault, motion)
