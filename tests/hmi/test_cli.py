"""``cellctl hmi user …`` and ``cellctl hmi`` as an operator runs them."""

from __future__ import annotations

import http.client
import io
import os
import stat
import subprocess
import sys
import time
from pathlib import Path

from cellctl.cli import main
from cellctl.hmi.auth import verify_password
from cellctl.hmi.config import load_hmi_config
from tests.conftest import free_port

REPO = Path(__file__).resolve().parents[2]


def test_user_add_stores_only_a_hash_in_a_private_file(tmp_path, monkeypatch, capsys) -> None:
    path = tmp_path / "hmi.yaml"
    monkeypatch.setattr(sys, "stdin", io.StringIO("s3cret-password\n"))
    assert (
        main(["hmi", "user", "add", "alice", "--role", "operator", "--password-stdin", "--hmi-config", str(path)]) == 0
    )
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert "s3cret-password" not in path.read_text()
    (u,) = load_hmi_config(path).users
    assert (u.name, u.role) == ("alice", "operator") and verify_password("s3cret-password", u.password_hash)
    monkeypatch.setattr(sys, "stdin", io.StringIO("short\n"))
    assert main(["hmi", "user", "add", "bob", "--role", "operator", "--password-stdin", "--hmi-config", str(path)]) == 2
    assert "at least 8" in capsys.readouterr().err
    assert main(["hmi", "user", "remove", "nobody", "--hmi-config", str(path)]) == 2
    assert main(["hmi", "user", "remove", "alice", "--hmi-config", str(path)]) == 0
    assert load_hmi_config(path).users == []


def test_cellctl_hmi_serves_and_says_the_cell_is_unreachable(tmp_path, port) -> None:
    http_port = free_port()
    (tmp_path / "hmi.yaml").write_text(f"port: {http_port}\n")
    ep = f'["tcp/127.0.0.1:{port}"]'
    cmd = [sys.executable, "-m", "cellctl", "hmi", "--hmi-config", str(tmp_path / "hmi.yaml"),
           "--set", f"bus.connect={ep}", "--set", f"recording.dir={tmp_path}/logs",
           "--set", f"recording.index={tmp_path}/logs/cells.db"]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=REPO, stderr=subprocess.PIPE, env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                c = http.client.HTTPConnection("127.0.0.1", http_port, timeout=5)
                c.request("GET", "/api/status")
                r = c.getresponse()
                body = r.read()
                break
            except OSError:
                assert proc.poll() is None and time.monotonic() < deadline, "cellctl hmi did not start"
                time.sleep(0.2)
        assert r.status == 503 and b'"reachable":false' in body
    finally:
        proc.terminate()
        err = proc.communicate(timeout=15)[1].decode()
    assert "read-only" in err and f"http://127.0.0.1:{http_port}" in err
