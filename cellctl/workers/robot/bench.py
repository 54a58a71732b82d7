"""``cellctl bench ur``: the UR backend against the emulated controller (through real ur-rtde).

* ``protective_stop_to_safe_state_ms``: protective stop injected during a motion → the worker has
  latched the fault, sent ``stopJ`` and (in a worker) withdrawn its token — the moment the
  supervisor's liveliness subscriber is told (it then holds/aborts at once). ≥ 20 injections.
* ``supervisor_loss_to_stopped_ms``: ``stop("supervisor lost")`` (what the token subscriber calls)
  during a motion → the controller reports the arm at rest.
* ``tracking_error_rad``: the arm's deviation from the planned path, every sample of every motion.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from cellctl.bench_options import BenchOptions

__all__ = ["bench_ur"]


def _stats(xs: list[float], digits: int = 1) -> dict[str, float | int]:
    a = np.asarray(xs, dtype=float)
    return {"p50": round(float(np.median(a)), digits), "max": round(float(a.max()), digits), "n": int(len(a))}


def _rest(emu) -> None:  # noqa: ANN001 - EmulatorProcess
    deadline = time.monotonic() + 10
    while emu.state()["moving"] and time.monotonic() < deadline:
        time.sleep(0.005)


def bench_ur(opts: BenchOptions) -> dict[str, object]:
    from cellctl.config import load_config
    from cellctl.errors import RobotError
    from cellctl.messages import MoveRequest, RobotMaintenanceRequest
    from cellctl.sim.ur_controller import EmulatorProcess, free_loopback_host
    from cellctl.workers.robot import make_robot

    n = opts.n or 20
    host = free_loopback_host()
    emu_over = ["sim.ur_controller.unlock_delay_s=0"]
    over = [
        "robot.backend=ur",
        f"robot.ur.host={host}",
        "robot.settle_s=0",
        "robot.speed_fraction=0.2",
        "robot.ur.faults.data_stale_ms=300",
        "robot.ur.faults.watchdog_hz=2",
        *opts.overrides,
    ]
    cfg = load_config(opts.config, over)
    pstop: list[float] = []
    sup: list[float] = []
    wrist = np.array([0, 0, 0, 0, 0, 1.0])
    with EmulatorProcess(host, emu_over) as emu:
        robot = make_robot(cfg)
        try:

            def motion() -> tuple[threading.Thread, list[Exception]]:
                q = robot.joints
                goal = q + (-1.5 if q[5] > 0 else 1.5) * wrist
                errs: list[Exception] = []

                def go() -> None:
                    try:
                        robot.move(MoveRequest(joints=goal.tolist()))
                    except RobotError as err:
                        errs.append(err)

                t = threading.Thread(target=go, daemon=True)
                t.start()
                deadline = time.monotonic() + 10
                while not emu.state()["moving"] and time.monotonic() < deadline and not errs:
                    time.sleep(0.005)
                if errs:
                    raise errs[0]
                time.sleep(0.2)
                return t, errs

            for _ in range(n):
                t, _errs = motion()
                k = len(robot.fault_log)
                t0 = time.monotonic()
                emu.inject("protective_stop bench")
                t.join(timeout=10)
                if len(robot.fault_log) > k:
                    pstop.append(1e3 * (robot.fault_log[k][0] - t0))
                _rest(emu)
                robot.maintenance(RobotMaintenanceRequest(action="unlock_protective_stop", user="bench"))
                robot.maintenance(RobotMaintenanceRequest(action="clear_fault", user="bench"))
            for _ in range(max(5, n // 2)):
                t, _errs = motion()
                t0 = time.monotonic()
                robot.stop("supervisor lost (liveliness token gone)")
                while emu.state()["moving"]:
                    time.sleep(0.002)
                sup.append(1e3 * (time.monotonic() - t0))
                t.join(timeout=10)
            track = list(robot.tracking)
        finally:
            robot.close()
    return {
        "protective_stop_to_safe_state_ms": _stats(pstop),
        "supervisor_loss_to_stopped_ms": _stats(sup),
        "tracking_error_rad": {k: v for k, v in _stats(track, 6).items() if k != "n"} | {"samples": len(track)},
        "setup": {
            "controller": "cellctl sim ur-controller (emulated UR10e, 500 Hz) through ur-rtde 1.6.5",
            "safe_state": "fault latched + stopJ sent + token withdrawn (worker side)",
            "stopped": "the controller reports the arm at rest (stopJ at robot.ur.stop_decel)",
            "tracking": "max joint deviation from the planned piecewise-linear path",
            "speed_fraction": cfg.robot.speed_fraction,
            "stop_decel_rad_s2": cfg.robot.ur.stop_decel,
        },
    }
