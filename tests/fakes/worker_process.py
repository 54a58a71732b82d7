"""One worker double as its own process, so tests can SIGKILL or SIGSTOP it (tests only).

``python -m tests.fakes.worker_process ROLE [--delay OP=SECONDS ...] [--miss] --set ...`` serves
ROLE's ops like :class:`tests.fakes.workers.FakeCell`, each op taking the given time, until
SIGTERM.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

from cellctl.config import load_config
from tests.fakes.workers import FakeCell

ROOT = Path(__file__).resolve().parents[2]


def spawn(role: str, overrides: list[str], delays: dict[str, float], miss: bool = False) -> subprocess.Popen[bytes]:
    """Start the double for ``role`` as a child process."""
    cmd = [sys.executable, "-m", "tests.fakes.worker_process", role]
    for op, sec in delays.items():
        cmd += ["--delay", f"{op}={sec}"]
    if miss:
        cmd.append("--miss")
    for ov in overrides:
        cmd += ["--set", ov]
    return subprocess.Popen(cmd, cwd=ROOT, stdin=subprocess.DEVNULL, start_new_session=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("role")
    ap.add_argument("--delay", action="append", default=[])
    ap.add_argument("--miss", action="store_true", help="planner: every lookup misses")
    ap.add_argument("--set", dest="overrides", action="append", default=[])
    a = ap.parse_args()
    cfg = load_config(None, a.overrides)
    delays = {k: float(v) for k, v in (d.split("=", 1) for d in a.delay)}
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with FakeCell(cfg, roles=(a.role,), n_viewpoints=4, plan_hit=not a.miss, delays=delays):
        stop.wait()
    os._exit(0)


if __name__ == "__main__":
    main()
