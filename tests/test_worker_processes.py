"""The daemon's child workers: a dead one is started again, with a back-off."""

from __future__ import annotations

import signal
import time

from cellctl.app import WorkerProcesses
from cellctl.bus.session import open_session


def _killed(procs: WorkerProcesses, role: str) -> int:
    p = procs.procs[role]
    p.send_signal(signal.SIGKILL)
    p.wait(10)
    return p.pid


def test_a_dead_child_worker_is_restarted_with_back_off(cfg) -> None:
    router = open_session(cfg, "router")  # so the children have something to connect to
    procs = WorkerProcesses(cfg, None, [f"bus.listen={cfg.bus.listen}", f"bus.connect={cfg.bus.connect}"], ["planner"])
    procs.start()
    try:
        assert procs.restart_dead() == []  # alive: left alone
        old = _killed(procs, "planner")
        assert procs.restart_dead() == ["planner"]
        assert procs.procs["planner"].pid != old and procs.procs["planner"].poll() is None
        _killed(procs, "planner")
        assert procs.restart_dead() == []  # within the back-off
        time.sleep(1.1)
        assert procs.restart_dead() == ["planner"]
    finally:
        procs.stop()
        router.close()
