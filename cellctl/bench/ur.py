"""``cellctl bench ur``: the UR backend against the emulated controller (through real ur-rtde).

* ``protective_stop_to_safe_state_ms``: a protective stop injected while the arm moves in a cycle's
  approach → the **supervisor** in Held or Aborted (``supervisor.on_worker_lost``). The whole
  daemon runs: ``build_cell(with_workers=True)`` (the real sim camera, classifier and planner
  workers, the UR robot worker against the emulator, as ``cellctl demo --robot ur``); the
  supervisor is in this process and its state is polled every 0.5 ms. ≥ 20 injections, each
  followed by the operator's recovery (``robot/maintenance``: unlock, clear_fault) and PackML
  Clear/Reset.
* ``supervisor_loss_to_stopped_ms``: ``stop("supervisor lost")`` (what the token subscriber calls)
  during a motion → the controller reports the arm at rest (a backend in this process).
* ``tracking_error_rad``: the arm's deviation from the planned path, every sample of those motions.
"""

from __future__ import annotations

import os
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from cellctl.bench.options import BenchOptions

__all__ = ["bench_ur"]

SAFE_STATES = ("Held", "Aborted")


def _stats(xs: list[float], digits: int = 1) -> dict[str, float | int]:
    if not xs:
        return {"p50": float("nan"), "max": float("nan"), "n": 0}
    a = np.asarray(xs, dtype=float)
    return {"p50": round(float(np.median(a)), digits), "max": round(float(a.max()), digits), "n": int(len(a))}


def _wait(pred: Any, timeout_s: float, what: str, period: float = 0.005) -> float:
    """Poll until ``pred()``; the monotonic time it first held. Raises RuntimeError naming ``what``."""
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise RuntimeError(f"bench ur: {what} not reached within {timeout_s:g} s")
        time.sleep(period)
    return time.monotonic()


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


_UR = [
    "robot.backend=ur",
    "robot.settle_s=0",
    "robot.ur.faults.watchdog_hz=2",
]


def _supervisor_phase(opts: BenchOptions, n: int, out: Path) -> tuple[list[float], dict[str, Any]]:
    """n protective stops in a cycle's approach motion → supervisor Held/Aborted (ms)."""
    from cellctl.app import build_cell
    from cellctl.bus import keys
    from cellctl.bus.plc_client import PlcClient
    from cellctl.bus.rpc import request
    from cellctl.config import load_config, output_overrides
    from cellctl.messages import RobotMaintenanceReply, RobotMaintenanceRequest
    from cellctl.sim.ur_controller import EmulatorProcess, free_loopback_host

    host = free_loopback_host()
    ep = f'["tcp/127.0.0.1:{_free_port()}"]'
    overrides = [
        f"bus.listen={ep}",
        f"bus.connect={ep}",
        *_UR,
        f"robot.ur.host={host}",
        f"sim.ur_controller.host={host}",
        "sim.ur_controller.unlock_delay_s=0",
        "robot.ur.twin=true",
        "robot.speed_fraction=0.5",
        "robot.speed_scale=20",  # the twin's base parks in 0.2 s
        "robot.ur.faults.data_stale_ms=1000",  # a Python emulator on a loaded machine sends late now and then
        *output_overrides(out),
        *opts.overrides,
    ]
    cfg = load_config(opts.config, overrides)
    c = cfg.cell_id
    times: list[float] = []
    reasons: dict[str, int] = {}
    states: dict[str, int] = {}
    with (
        EmulatorProcess(host, overrides, opts.config, out / "ur-controller.log") as emu,
        build_cell(cfg, with_workers=True, config_file=opts.config, overrides=overrides) as cell,
    ):
        sup = cell.supervisor
        plc = PlcClient(cfg, "bench")
        try:
            if not plc.wait_workers(("robot", "camera", "classifier", "planner"), 180):
                raise RuntimeError(f"bench ur: workers did not come up: {sup.status.workers}")

            def maintain(action: str) -> None:
                req = RobotMaintenanceRequest(action=action, user="bench")
                request(plc.session, keys.robot_op(c, "maintenance"), req, RobotMaintenanceReply, timeout=30)

            for _ in range(n):
                if plc.command("reset", timeout=10).accepted:
                    _wait(lambda: sup.state == "Idle", 30, "Idle")
                if not plc.command("start", timeout=10).accepted:
                    raise RuntimeError(f"bench ur: start refused in {sup.state}")
                _wait(lambda: sup.state == "Execute.approaching" and emu.state()["moving"], 60, "approach motion")
                t0 = time.monotonic()
                emu.inject("protective_stop bench")
                t1 = _wait(lambda: sup.top_state in SAFE_STATES, 10, "Held/Aborted", period=0.0005)
                times.append(1e3 * (t1 - t0))
                states[sup.top_state] = states.get(sup.top_state, 0) + 1
                res = plc.results.get(timeout=30) if sup.top_state == "Aborted" else None
                why = (res.reason if res is not None else sup.status.last_error) or "-"
                key = why.split(" at [")[0]  # joints differ per injection
                reasons[key] = reasons.get(key, 0) + 1
                _wait(lambda: not emu.state()["moving"], 10, "arm at rest")
                maintain("unlock_protective_stop")
                maintain("clear_fault")
                _wait(lambda: sup.status.workers.get("robot", False), 30, "robot worker back")
                if sup.top_state == "Held":
                    plc.command("abort", timeout=10)
                    _wait(lambda: sup.top_state == "Aborted", 30, "Aborted")
                plc.command("clear", timeout=10)
                _wait(lambda: sup.top_state == "Stopped", 30, "Stopped")
        finally:
            plc.close()
    return times, {"reasons": reasons, "states": states, "on_worker_lost": cfg.supervisor.on_worker_lost}


def _worker_phase(opts: BenchOptions, n: int) -> tuple[list[float], list[float], Any]:
    """supervisor loss → arm at rest (ms) and the tracking error, on a backend in this process."""
    from cellctl.config import load_config
    from cellctl.errors import RobotError
    from cellctl.messages import MoveRequest
    from cellctl.sim.ur_controller import EmulatorProcess, free_loopback_host
    from cellctl.workers.robot import make_robot

    host = free_loopback_host()
    over = [*_UR, f"robot.ur.host={host}", "robot.speed_fraction=0.2", "robot.ur.faults.data_stale_ms=1000"]
    cfg = load_config(opts.config, [*over, *opts.overrides])
    sup: list[float] = []
    wrist = np.array([0, 0, 0, 0, 0, 1.0])
    with EmulatorProcess(host, ["sim.ur_controller.unlock_delay_s=0"]) as emu:
        robot = make_robot(cfg)
        try:
            for _ in range(n):
                q = robot.joints
                goal = q + (-1.5 if q[5] > 0 else 1.5) * wrist
                errs: list[Exception] = []

                def go(goal: Any = goal, errs: list[Exception] = errs) -> None:
                    try:
                        robot.move(MoveRequest(joints=goal.tolist()))
                    except RobotError as err:
                        errs.append(err)

                t = threading.Thread(target=go, daemon=True)
                t.start()
                _wait(lambda errs=errs: emu.state()["moving"] or bool(errs), 10, "motion")
                if errs:
                    raise errs[0]
                time.sleep(0.2)
                t0 = time.monotonic()
                robot.stop("supervisor lost (liveliness token gone)")
                t1 = _wait(lambda: not emu.state()["moving"], 10, "arm at rest", period=0.002)
                sup.append(1e3 * (t1 - t0))
                t.join(timeout=10)
            track = list(robot.tracking)
        finally:
            robot.close()
    return sup, track, cfg


def bench_ur(opts: BenchOptions) -> dict[str, object]:
    n = opts.n or 20
    load0 = os.getloadavg()[0]
    cpu0 = time.process_time()
    wall0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="bench-ur-") as tmp:  # cycle logs, index, plan cache
        pstop, seen = _supervisor_phase(opts, n, Path(tmp))
    sup, track, cfg = _worker_phase(opts, max(5, n // 2))
    return {
        "protective_stop_to_safe_state_ms": _stats(pstop),
        "supervisor_loss_to_stopped_ms": _stats(sup),
        "tracking_error_rad": {k: v for k, v in _stats(track, 6).items() if k != "n"} | {"samples": len(track)},
        "setup": {
            "controller": "cellctl sim ur-controller (emulated UR10e, 500 Hz) through ur-rtde 1.6.5",
            "safe_state": "protective stop injected in a cycle's approach motion -> supervisor Held/Aborted "
            "(the daemon with every worker, as cellctl demo --robot ur; supervisor state polled every 0.5 ms)",
            "safe_state_seen": seen,
            "stopped": "the controller reports the arm at rest (stopJ at robot.ur.stop_decel)",
            "tracking": "max joint deviation from the planned piecewise-linear path",
            "speed_fraction": cfg.robot.speed_fraction,
            "stop_decel_rad_s2": cfg.robot.ur.stop_decel,
            "load_avg_1m": [round(load0, 2), round(os.getloadavg()[0], 2)],
            "bench_process_cpu_s": round(time.process_time() - cpu0, 1),
            "wall_s": round(time.monotonic() - wall0, 1),
        },
    }
