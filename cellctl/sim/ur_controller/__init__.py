"""``cellctl sim ur-controller``: an offline UR10e controller that ur-rtde talks to on loopback.

RTDE (30004: protocol negotiation, output/input recipes, 500 Hz data), the script interface
(30003/30002) that ``RTDEControlInterface`` uploads its ``rtde_control`` program to, that
program's register handshake, and enough of the dashboard server (29999). The arm it moves is
the twin's arm: its joints reach the twin the way a real arm's reach a real cell, through RTDE
(``getActualQ``), published by the robot worker. What it emulates and what not:
``docs/twin/ur_controller.md``.
"""

from cellctl.sim.ur_controller._controller import RobotMode, RuntimeState, SafetyMode, UrController, UrIdentity
from cellctl.sim.ur_controller._process import EmulatorProcess, free_loopback_host
from cellctl.sim.ur_controller._servers import Ports, UrControllerServers

__all__ = [
    "EmulatorProcess",
    "Ports",
    "RobotMode",
    "RuntimeState",
    "SafetyMode",
    "UrController",
    "UrControllerServers",
    "UrIdentity",
    "build",
    "free_loopback_host",
    "run",
]


def build(cfg, host: str | None = None) -> tuple[UrController, UrControllerServers]:  # CellConfig
    """The emulator of ``cfg.sim.ur_controller``, listening (arm at the twin's home pose).

    Raises:
        ConfigError: a non-loopback host or a port in use.
    """
    from cellctl.sim import scene

    c = cfg.sim.ur_controller
    ctl = UrController(
        scene.HOME_JOINTS.copy(),
        identity=UrIdentity(model=c.model, serial=c.serial, polyscope=c.polyscope),
        robot_mode=RobotMode[c.robot_mode],
        remote_control=c.remote_control,
        unlock_delay_s=c.unlock_delay_s,
        stop_decel=c.stop_decel,
    )
    srv = UrControllerServers(ctl, host or c.host, Ports(control=c.control_port))
    return ctl, srv


def run(cfg, stop, host: str | None = None) -> None:  # CellConfig, threading.Event
    """Serve until ``stop`` is set; prints ``ur-controller ready on HOST`` to stderr when listening."""
    import sys

    ctl, srv = build(cfg, host)
    print(f"ur-controller ready on {srv.host} (control port {srv.ports.control})", file=sys.stderr, flush=True)
    try:
        stop.wait()
    finally:
        srv.close()
