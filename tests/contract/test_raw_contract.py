"""The documented contract, exercised by a process that imports only zenoh against a real
`cellctl run` daemon process (which also proves SIGTERM shuts it down cleanly)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
from pathlib import Path

from tests.conftest import free_port

HERE = Path(__file__).parent


def test_raw_zenoh_client_drives_the_daemon(tmp_path: Path) -> None:
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    daemon = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "cellctl",
            "run",
            "--set",
            f'bus.listen=["{ep}"]',
            "--set",
            f"recording.dir={tmp_path}",
            "--set",
            f"recording.index={tmp_path / 'cells.db'}",
        ],
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: list[str] = []
    listening = threading.Event()

    def drain() -> None:  # also keeps the pipe from filling up
        for line in daemon.stderr:
            lines.append(line)
            if "listening on" in line:
                listening.set()

    threading.Thread(target=drain, daemon=True).start()
    try:
        assert listening.wait(30), "daemon not listening within 30 s:\n" + "".join(lines)
        out = subprocess.run(
            [sys.executable, str(HERE / "raw_plc.py"), ep, "cell1"], capture_output=True, text=True, timeout=60
        )
        checks = [json.loads(line) for line in out.stdout.splitlines()]
        assert out.returncode == 0, out.stdout + out.stderr
        assert [c["check"] for c in checks if c["ok"]] == [
            "status_readable",
            "reset_by_query",
            "reached_idle",
            "start_by_put_cntrl_cmd",
            "aborted_without_workers",
            "bad_command_rejected",
            "clear_by_put",
            "stop_by_put",
            "abort_by_query",
            "aborted",
        ]
    finally:
        daemon.send_signal(signal.SIGTERM)
        rc = daemon.wait(timeout=15)
    assert rc == 0
    logs = list(tmp_path.glob("*/*.mcap"))
    assert len(logs) == 1  # the one aborted cycle, closed properly
