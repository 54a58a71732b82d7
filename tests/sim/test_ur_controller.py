"""The UR controller emulator, driven by the real, unmodified ur-rtde library.

ur-rtde fixes the RTDE/script/dashboard ports, so the emulator gets its own loopback address
(127.77.x.y, from the pid): test processes running in parallel do not collide.
"""

from __future__ import annotations

import socket
import struct
import time

import dashboard_client
import numpy as np
import pytest
import rtde_control
import rtde_receive

from cellctl.sim import scene
from cellctl.sim.ur_controller import EmulatorProcess, free_loopback_host


@pytest.fixture(scope="module")
def emu():
    with EmulatorProcess(free_loopback_host(), ["sim.ur_controller.unlock_delay_s=0.5"]) as e:
        yield e


@pytest.fixture
def healthy(emu):
    emu.inject("reset")
    yield emu
    emu.inject("reset")


@pytest.fixture
def ur(healthy):
    r = rtde_receive.RTDEReceiveInterface(healthy.host)
    c = rtde_control.RTDEControlInterface(healthy.host)
    yield healthy, c, r
    c.disconnect()  # before the emulator can go: ur-rtde would otherwise try to reconnect
    r.disconnect()


def _settled(emu, timeout_s: float = 10.0) -> list[float]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        st = emu.state()
        if not st["moving"]:
            return st["q"]
        time.sleep(0.05)
    raise AssertionError("the emulated arm did not come to rest")


def test_receive_interface_reads_the_twin_arm_joints(healthy) -> None:
    r = rtde_receive.RTDEReceiveInterface(healthy.host)
    try:
        assert np.abs(np.array(r.getActualQ()) - healthy.state()["q"]).max() < 1e-4
        assert np.abs(np.array(r.getActualQ()) - scene.HOME_JOINTS).max() < 1e-4
        assert r.getRobotMode() == 7 and r.getSafetyMode() == 1 and not r.isProtectiveStopped()
        t0 = r.getTimestamp()
        time.sleep(0.2)
        assert r.getTimestamp() > t0  # data packages keep coming (500 Hz)
    finally:
        r.disconnect()


def test_movej_moves_the_arm_and_stopj_stops_it(ur) -> None:
    emu, c, r = ur
    q0 = np.array(r.getActualQ())
    target = q0 + np.array([0.4, -0.3, 0.3, 0.2, -0.2, 0.5])
    assert c.moveJ(target.tolist(), 1.0, 1.4)  # synchronous: returns at the goal
    assert np.abs(np.array(emu.state()["q"]) - target).max() < 1e-4
    time.sleep(0.05)
    assert np.abs(np.array(r.getActualQ()) - emu.state()["q"]).max() < 1e-4
    # asynchronous back, stopped half way
    assert c.moveJ(q0.tolist(), 0.5, 1.0, True)
    time.sleep(0.5)
    assert c.getAsyncOperationProgressEx().isAsyncOperationRunning()
    c.stopJ(2.0)
    q_stop = np.array(_settled(emu))
    assert np.abs(q_stop - target).max() > 0.05 and np.abs(q_stop - q0).max() > 0.05
    time.sleep(0.3)
    assert np.abs(np.array(emu.state()["q"]) - q_stop).max() < 1e-9  # and stays stopped
    assert not c.getAsyncOperationProgressEx().isAsyncOperationRunning()


def test_movej_path_visits_the_waypoints(ur) -> None:
    emu, c, r = ur
    q0 = np.array(r.getActualQ())
    path = [[*(q0 + 0.2).tolist(), 1.0, 1.4, 0.0], [*q0.tolist(), 1.0, 1.4, 0.0]]
    assert c.moveJ(path)
    assert np.abs(np.array(emu.state()["q"]) - q0).max() < 1e-4


def test_commands_during_a_protective_stop_fail_and_recovery_needs_the_unlock(ur) -> None:
    emu, c, r = ur
    q0 = np.array(r.getActualQ())
    emu.inject("protective_stop injected")
    time.sleep(0.1)
    assert r.isProtectiveStopped()
    assert c.moveJ((q0 + 0.2).tolist(), 1.0, 1.4) is False
    assert np.abs(np.array(emu.state()["q"]) - q0).max() < 1e-9  # no motion
    d = dashboard_client.DashboardClient(emu.host)
    d.connect()
    try:
        assert d.safetystatus() == "Safetystatus: PROTECTIVE_STOP"
        with pytest.raises(RuntimeError, match="Cannot unlock protective stop until 0.5s after occurrence"):
            d.unlockProtectiveStop()
        time.sleep(0.6)
        d.unlockProtectiveStop()
    finally:
        d.disconnect()
    assert c.reuploadScript()  # returns once sent: the program starts a moment later
    deadline = time.monotonic() + 5
    while not c.isProgramRunning() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert c.moveJ((q0 + 0.1).tolist(), 1.0, 1.4)


def test_the_dashboard_answers_like_an_e_series_controller(healthy) -> None:
    d = dashboard_client.DashboardClient(healthy.host)
    d.connect()
    try:
        assert d.robotmode() == "Robotmode: RUNNING"
        assert d.getRobotModel() == "UR10" and d.polyscopeVersion() == "5.11.1.108318"
        assert d.isInRemoteControl()
        healthy.inject("power_off")
        assert d.robotmode() == "Robotmode: POWER_OFF"
        d.powerOn()
        assert d.robotmode() == "Robotmode: IDLE"  # powered, brakes still locked
        d.brakeRelease()
        assert d.robotmode() == "Robotmode: RUNNING"
        d.send("fly away\n")
        assert d.receive() == "could not understand: 'fly away'"
    finally:
        d.disconnect()


def test_a_controller_holding_the_input_registers_refuses_the_recipe(healthy) -> None:
    healthy.inject("inputs_in_use input_int_register_0")
    with pytest.raises(RuntimeError, match="RTDE input registers are already in use"):
        rtde_control.RTDEControlInterface(healthy.host)


def _pkg(kind: str, payload: bytes = b"") -> bytes:
    return struct.pack(">HB", 3 + len(payload), ord(kind)) + payload


def _reply(s: socket.socket) -> tuple[str, bytes]:
    size, kind = struct.unpack(">HB", s.recv(3))
    body = b""
    while len(body) < size - 3:
        body += s.recv(size - 3 - len(body))
    return chr(kind), body


def test_rtde_negotiation_refuses_an_unknown_version_and_unknown_variables(healthy) -> None:
    with socket.create_connection((healthy.host, 30004), timeout=5) as s:
        s.sendall(_pkg("V", struct.pack(">H", 9)))
        assert _reply(s) == ("V", b"\x00")
        s.sendall(_pkg("V", struct.pack(">H", 2)))
        assert _reply(s) == ("V", b"\x01")
        s.sendall(_pkg("v"))
        kind, body = _reply(s)
        assert kind == "v" and struct.unpack(">IIII", body) == (5, 11, 1, 108318)
        s.sendall(_pkg("O", struct.pack(">d", 125.0) + b"actual_q,no_such_variable"))
        assert _reply(s) == ("O", b"\x00VECTOR6D,NOT_FOUND")
        s.sendall(_pkg("O", struct.pack(">d", 125.0) + b"timestamp,actual_q"))
        assert _reply(s) == ("O", b"\x01DOUBLE,VECTOR6D")
        s.sendall(_pkg("S"))
        assert _reply(s) == ("S", b"\x01")
        kind, body = _reply(s)
        assert kind == "U" and body[0] == 1 and len(body) == 1 + 8 + 48
        q = struct.unpack(">6d", body[9:])
        assert np.abs(np.array(q) - healthy.state()["q"]).max() < 1e-4


def _program(*targets: list[float]) -> str:
    """An rtde_control program as ur-rtde sends it for moveJ(path) (the parts the emulator reads)."""
    lines = [f"        movej([{','.join(map(str, q))}],a=1.4,v=1.05,r=0)" for q in targets]
    return (
        "def rtde_control():\n    global reg_offset_int = 0\n    def exec_move_path():\n"
        + "\n".join(lines)
        + "\n    end\nend\n"
    )


def test_a_command_that_lands_with_the_clear_between_two_ticks_is_run() -> None:
    """ur-rtde's moveJ(path): stop-script (255), clear (0), upload, then MOVE_PATH (45). Under load the
    clear and the 45 reach the register between two controller ticks; the 45 must still run (it once
    waited for a 0 it never saw, and ur-rtde waited for "done" forever)."""
    from cellctl.sim.ur_controller import RuntimeState, UrController
    from cellctl.sim.ur_controller._controller import CMD_MOVE_PATH, CMD_STOP_SCRIPT

    ctl = UrController(scene.HOME_JOINTS.copy())
    goal = (scene.HOME_JOINTS + 0.1).tolist()
    with ctl.lock:
        ctl.set_input("input_int_register_0", CMD_STOP_SCRIPT)  # the stop that preceded the upload
    ctl.upload_script(_program(goal))
    ctl.tick(0.002)
    assert ctl.runtime_state == RuntimeState.PLAYING  # the stale stop code is not run
    with ctl.lock:
        ctl.set_input("input_int_register_1", 1)  # async
        ctl.set_input("input_int_register_0", 0)
        ctl.set_input("input_int_register_0", CMD_MOVE_PATH)
    ctl.tick(0.002)
    assert ctl.register("output_int_register_0") == 2  # done with the command
    assert ctl.moving


def test_a_stale_stop_code_left_from_the_program_before_is_not_run() -> None:
    from cellctl.sim.ur_controller import RuntimeState, UrController
    from cellctl.sim.ur_controller._controller import CMD_STOP_SCRIPT

    ctl = UrController(scene.HOME_JOINTS.copy())
    with ctl.lock:
        ctl.set_input("input_int_register_0", CMD_STOP_SCRIPT)
    ctl.upload_script(_program())
    for _ in range(5):
        ctl.tick(0.002)
    assert ctl.runtime_state == RuntimeState.PLAYING
    with ctl.lock:
        ctl.set_input("input_int_register_0", 0)
    ctl.tick(0.002)
    assert ctl.register("output_int_register_0") == 1  # ready
    with ctl.lock:
        ctl.set_input("input_int_register_0", CMD_STOP_SCRIPT)  # a fresh stop is run
    ctl.tick(0.002)
    assert ctl.runtime_state == RuntimeState.STOPPED
