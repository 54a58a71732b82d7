"""robot.backend: ur against the emulated controller, through the real ur-rtde library.

Bad input and every injected fault: a clear error naming the condition, no motion (or the arm
stopped where it was), the backend keeps serving, and a good motion after the operator's
recovery. The emulator runs in its own process on its own loopback address (ur-rtde fixes ports).
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from cellctl.config import load_config
from cellctl.errors import RobotError
from cellctl.messages import MoveRequest, RobotMaintenanceRequest
from cellctl.sim import scene
from cellctl.sim.ur_controller import EmulatorProcess, free_loopback_host
from cellctl.workers.robot import make_robot

# ur-rtde calls block holding the GIL, so a hang there is only ended by the thread method
pytestmark = pytest.mark.timeout(240, method="thread")

WRIST = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1.0])


@pytest.fixture(scope="module")
def emu(tmp_path_factory):
    with EmulatorProcess(
        free_loopback_host(),
        ["sim.ur_controller.unlock_delay_s=0.3"],
        log_path=tmp_path_factory.mktemp("emu") / "ur-controller.log",
    ) as e:
        print(e.host)
        yield e


def _cfg(emu, *extra: str):
    return load_config(
        None,
        [
            "robot.backend=ur",
            f"robot.ur.host={emu.host}",
            "robot.settle_s=0",
            "robot.ur.connect_attempts=1",
            "robot.ur.faults.data_stale_ms=1000",  # a Python emulator on a loaded machine sends late now and then
            "robot.ur.faults.watchdog_hz=2",
            *extra,
        ],  # loaded machine
    )


@pytest.fixture
def robot(emu):
    emu.inject("reset")
    r = make_robot(_cfg(emu, "robot.speed_fraction=0.15"))
    yield r
    r.close()
    emu.inject("reset")


def _maint(robot, action: str):
    return robot.maintenance(RobotMaintenanceRequest(action=action, user="test"))


class _Mover(threading.Thread):
    def __init__(self, robot, q) -> None:
        super().__init__(daemon=True)
        self.robot, self.q, self.error, self.reply = robot, q, None, None

    def run(self) -> None:
        try:
            self.reply = self.robot.move(MoveRequest(joints=list(self.q)))
        except RobotError as err:
            self.error = err


def _wait_moving(emu, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not emu.state()["moving"]:
        assert time.monotonic() < deadline, "the arm never started"
        time.sleep(0.02)


def _rest(emu, timeout_s: float = 10.0) -> np.ndarray:
    deadline = time.monotonic() + timeout_s
    while emu.state()["moving"]:
        assert time.monotonic() < deadline, "the arm did not stop"
        time.sleep(0.02)
    return np.array(emu.state()["q"])


def _long_goal(robot) -> np.ndarray:
    """2 rad of wrist 3, towards 0 (the tests' motions must not walk out of the joint limits)."""
    start = robot.joints
    return start + (-2.0 if start[5] > 0 else 2.0) * WRIST


def _faulted_motion(robot, emu, fault: str) -> tuple[Exception, np.ndarray, np.ndarray]:
    start = robot.joints
    goal = _long_goal(robot)
    m = _Mover(robot, goal)
    m.start()
    _wait_moving(emu)
    time.sleep(0.3)
    emu.inject(fault)
    m.join(timeout=20)
    assert not m.is_alive() and m.error is not None, "the motion did not fail"
    q = _rest(emu)
    assert np.abs(q - goal).max() > 0.1 and np.abs(q - start).max() > 0.01  # stopped on the way
    time.sleep(0.5)
    assert np.abs(np.array(emu.state()["q"]) - q).max() < 1e-9  # and never resumed
    return m.error, q, goal


def test_move_runs_the_motion_module_trajectory_on_the_twin_arm(robot, emu) -> None:
    goal = scene.HOME_JOINTS + np.array([0.2, -0.15, 0.2, 0.3, -0.3, 0.5])
    reply = robot.move(MoveRequest(joints=goal.tolist()))
    assert np.abs(np.array(emu.state()["q"]) - goal).max() < 1e-4
    assert np.abs(np.array(reply.joints) - goal).max() < 1e-3
    expected = robot.trajectory(np.array([robot.last_path[0], *robot.last_path[1:]])).duration
    assert reply.duration_s == pytest.approx(expected, abs=1.0)
    assert max(robot.tracking) < 1e-3  # the arm stayed on the planned straight segments
    st = robot.state()
    assert st.speed_slider == pytest.approx(1.0) and st.fault is None and not st.moving


def test_the_speed_slider_is_read_and_slows_the_arm(robot, emu) -> None:
    emu.inject("slider 0.5")
    time.sleep(0.1)
    assert robot.state().speed_slider == pytest.approx(0.5)
    goal = robot.joints + (-0.5 if robot.joints[5] > 0 else 0.5) * WRIST
    t_plan = robot.trajectory(np.array([robot.joints, goal])).duration
    reply = robot.move(MoveRequest(joints=goal.tolist()))
    assert reply.duration_s > 1.6 * t_plan


@pytest.mark.parametrize(
    ("inject", "overrides", "match"),
    [
        ("mode POWER_OFF", [], r"not in RUNNING mode \(robot mode POWER_OFF\)"),
        ("mode IDLE", [], r"not in RUNNING mode \(robot mode IDLE\)"),
        ("local", [], "local control mode"),
        ("reset", ["robot.ur.expected_model=UR5e"], r"wrong robot model: the dashboard reports 'UR10'.*'UR5e'"),
        ("reset", ["robot.ur.expected_serial=X123"], r"serial number .20235500001.*X123"),
        ("protective_stop", [], "safety status is PROTECTIVE_STOP"),
        ("inputs_in_use input_int_register_0", [], "refused ur-rtde's RTDE recipe"),
    ],
)
def test_a_robot_that_cannot_run_programs_is_refused_naming_why(emu, inject, overrides, match) -> None:
    emu.inject("reset")
    emu.inject(inject)
    try:
        with pytest.raises(RobotError, match=match):
            make_robot(_cfg(emu, *overrides))
        assert not emu.state()["moving"]
    finally:
        emu.inject("reset")


def test_joint_targets_beyond_the_cells_limits_are_refused_without_motion(robot, emu) -> None:
    q = robot.joints.copy()
    q[0] = 7.0
    with pytest.raises(RobotError, match="target joints"):
        robot.move(MoveRequest(joints=q.tolist()))
    assert not emu.state()["moving"] and robot.state().fault is None


@pytest.mark.slow  # a motion, a fault, the recovery and another motion
def test_protective_stop_mid_motion_stops_the_arm_and_needs_the_operator(robot, emu) -> None:
    err, q, goal = _faulted_motion(robot, emu, "protective_stop injected")
    assert "protective stop" in str(err)
    assert robot.fault == "protective stop"
    rep = robot.fault_report  # the typed report the worker publishes on robot/fault
    assert rep is not None and rep.active and rep.condition == "protective_stop"
    assert rep.text == "robot fault: protective stop"
    assert (rep.robot_mode, rep.safety_mode) == ("RUNNING", "PROTECTIVE_STOP")
    assert {"protective_stopped", "stopped_due_to_safety"} <= set(rep.safety_flags)
    with pytest.raises(RobotError, match=r"UR fault active \(protective stop\)"):
        robot.move(MoveRequest(joints=goal.tolist()))
    assert robot.state().fault == "protective stop"  # still serving
    with pytest.raises(RobotError, match="protective stop is still active"):
        _maint(robot, "clear_fault")
    time.sleep(0.3)
    assert _maint(robot, "unlock_protective_stop").detail == "Protective stop releasing"
    assert robot.fault == "protective stop"  # never cleared by itself
    _maint(robot, "clear_fault")
    robot.move(MoveRequest(joints=goal.tolist()))
    assert np.abs(np.array(emu.state()["q"]) - goal).max() < 1e-4


@pytest.mark.slow  # a motion, a fault, the recovery and another motion
def test_emergency_stop_needs_power_on_and_brake_release(robot, emu) -> None:
    err, _, goal = _faulted_motion(robot, emu, "estop")
    assert "emergency stop" in str(err)
    emu.inject("estop_release")
    with pytest.raises(RobotError, match="robot mode POWER_OFF"):
        _maint(robot, "clear_fault")
    _maint(robot, "power_on")
    _maint(robot, "brake_release")
    _maint(robot, "clear_fault")
    robot.move(MoveRequest(joints=goal.tolist()))
    assert np.abs(np.array(emu.state()["q"]) - goal).max() < 1e-4


@pytest.mark.slow  # a motion, a fault, the recovery and another motion
@pytest.mark.parametrize(("fault", "clear", "text"), [("safeguard", "safeguard_reset", "safeguard stop"),
                                                      ("reduced", "reduced_off", "reduced mode")])  # fmt: skip
def test_safeguard_stop_and_reduced_mode_are_faults(robot, emu, fault, clear, text) -> None:
    err, _, goal = _faulted_motion(robot, emu, fault)
    assert text in str(err) and robot.fault == text
    emu.inject(clear)
    _maint(robot, "clear_fault")
    robot.move(MoveRequest(joints=goal.tolist()))


@pytest.mark.slow  # a motion, a fault, the recovery and another motion
@pytest.mark.parametrize("fault", ["drop 0.5", "stall 1.5"])  # a stall beyond data_stale_ms
def test_a_lost_or_stalled_controller_stops_the_motion_for_good(robot, emu, fault) -> None:
    err, q, goal = _faulted_motion(robot, emu, fault)
    assert "RTDE" in str(err)
    assert robot.fault_report is not None and robot.fault_report.condition in (
        ("lost_connection",) if fault.startswith("drop") else ("stall", "program_stopped", "lost_connection")
    )
    time.sleep(1.0)
    assert np.abs(np.array(emu.state()["q"]) - q).max() < 1e-9  # not resumed after the link came back
    assert robot.state().fault is not None
    _maint(robot, "clear_fault")
    robot.move(MoveRequest(joints=goal.tolist()))
    assert np.abs(np.array(emu.state()["q"]) - goal).max() < 1e-4


@pytest.mark.slow  # a motion, a fault, the recovery and another motion
def test_stop_interrupts_the_motion_at_once(robot, emu) -> None:
    start = robot.joints
    m = _Mover(robot, _long_goal(robot))
    m.start()
    _wait_moving(emu)
    time.sleep(0.3)
    robot.stop("supervisor lost (liveliness token gone)")
    m.join(timeout=10)
    assert m.error is not None and "supervisor lost" in str(m.error)
    _rest(emu)
    assert robot.fault is None  # a stop is not a fault: the next motion runs
    robot.move(MoveRequest(joints=start.tolist()))


def test_approach_parks_the_twin_base_at_a_whole_bin_station_and_observes_from_there(robot, emu) -> None:
    """ApproachRequest.base_pose (bin frame) as the sim backend does it: the twin's base parks at the
    station (with the seeded parking error), the arm is tucked first, and observes from a station."""
    from cellctl.geometry.transforms import pose_error, transform_from_xyz_rpy
    from cellctl.messages import ApproachRequest, PoseMsg

    robot.cfg.robot.speed_scale = 50.0  # the drive is modelled time
    bt = robot.catalog.get("case_study")
    mesh = robot.catalog.load_mesh("case_study")
    T_bin_station = transform_from_xyz_rpy((0, 0, 0), (0, 0, np.pi / 2)) @ scene.nominal_T_bin_base(bt, mesh)
    station = PoseMsg.from_matrix(T_bin_station, "bin")
    robot.approach(ApproachRequest(park=True, base_pose=station, observe=False))
    assert np.abs(np.array(emu.state()["q"]) - scene.HOME_JOINTS).max() < 1e-4  # tucked on the real arm
    T_world_base = robot.sim_state().world_T_base.matrix()
    dt, _ = pose_error(robot.scenario.T_world_bin(bt) @ T_bin_station, T_world_base)
    assert 0 < dt <= robot.cfg.sim.approach_error_m + 1e-9
    nominal = PoseMsg.from_matrix(scene.nominal_T_bin_base(bt, mesh), "bin")  # observation 0 is reachable there
    reply = robot.approach(ApproachRequest(park=True, base_pose=nominal, observe=True, observation_index=0))
    q = np.array(emu.state()["q"])
    assert np.abs(q - scene.HOME_JOINTS).max() > 0.05  # the emulated arm went to the observation pose
    assert np.abs(np.array(reply.joints) - q).max() < 1e-3


@pytest.mark.slow  # three motions
def test_a_stop_meant_for_an_earlier_motion_never_stops_a_later_one(robot, emu) -> None:
    """A stopJ that got the io lock only after a later motion began (a fault's stop behind a stalled
    call) is dropped; one for the motion in progress stops it."""
    start = robot.joints
    robot.move(MoveRequest(joints=(start + 0.2 * WRIST).tolist()))
    earlier = robot._motion_seq
    m = _Mover(robot, start)
    m.start()
    _wait_moving(emu)
    robot._stopj(earlier)  # late: dropped
    m.join(timeout=20)
    assert m.error is None and np.abs(np.array(emu.state()["q"]) - start).max() < 1e-4
    m = _Mover(robot, _long_goal(robot))
    m.start()
    _wait_moving(emu)
    robot._stopj(robot._motion_seq)  # the motion in progress: stopped
    m.join(timeout=20)
    assert m.error is not None and "short of its goal" in str(m.error)
    _rest(emu)


def test_clear_fault_waits_for_the_interrupted_motion_to_end(robot, emu) -> None:
    emu.inject("protective_stop injected")
    deadline = time.monotonic() + 5
    while robot.fault is None:
        assert time.monotonic() < deadline, "the protective stop was not noticed"
        time.sleep(0.01)
    time.sleep(0.3)
    _maint(robot, "unlock_protective_stop")
    robot._busy.acquire()  # the interrupted motion's request is still winding down
    done = threading.Event()
    t = threading.Thread(target=lambda: (_maint(robot, "clear_fault"), done.set()), daemon=True)
    t.start()
    try:
        assert not done.wait(0.5) and robot.fault == "protective stop"
    finally:
        robot._busy.release()
    assert done.wait(20) and robot.fault is None and robot.fault_report is None


def test_calls_queued_behind_a_wedged_call_never_run() -> None:
    """Once an interface is given up, what was queued behind the wedged call is dropped: run later on
    the old interface, ur-rtde would reconnect it and restart the control program under a fresh one."""
    from cellctl.workers.robot.ur._calls import CallThread, Wedged

    calls = CallThread("test-calls")
    release, ran = threading.Event(), []
    errors: list[Exception] = []

    def queued() -> None:
        try:
            calls.call(10.0, lambda: ran.append("queued"))
        except Wedged as err:
            errors.append(err)

    blocker = threading.Thread(target=lambda: pytest.raises(Wedged, calls.call, 0.3, release.wait), daemon=True)
    blocker.start()
    time.sleep(0.05)
    behind = threading.Thread(target=queued, daemon=True)
    behind.start()
    blocker.join(5)
    assert calls.wedged is not None
    release.set()  # the wedged call returns at last
    behind.join(5)
    assert ran == [] and len(errors) == 1 and "given up" in str(errors[0])
    with pytest.raises(Wedged):
        calls.call(1.0, lambda: ran.append("after"))
    assert ran == []


@pytest.mark.slow  # two motions
def test_a_motion_ends_on_fresh_joints_when_the_polled_ones_lag(robot, emu) -> None:
    """ur-rtde's 'finished' (control interface, 500 Hz) can overtake the joints the safety monitor last
    polled (receive interface, 125 Hz) on a loaded machine: the end is judged on joints read then, not on
    that sample (the 'ended 0.02 rad short of its goal (stopped)' after a stall's recovery)."""
    start = robot.joints
    goal = start + (-1.0 if start[5] > 0 else 1.0) * WRIST
    duration = robot.trajectory(np.array([start, goal])).duration
    lag = threading.Event()
    polled = robot._read_state

    def lagging(r=None):  # the monitor's poll sees nothing new while ``lag`` is set
        if lag.is_set() and threading.current_thread().name == "ur-safety-monitor" and robot._last_state is not None:
            return robot._last_state
        return polled(r)

    robot._read_state = lagging
    m = _Mover(robot, goal)
    m.start()
    _wait_moving(emu)
    time.sleep(max(duration - 0.25, 0.0))
    lag.set()  # the last quarter second of the motion: the polled joints stay where they were
    m.join(timeout=20)
    lag.clear()
    assert m.error is None, m.error
    assert np.abs(np.array(emu.state()["q"]) - goal).max() < 1e-4
