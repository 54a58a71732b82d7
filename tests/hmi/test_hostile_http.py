"""The HMI under a hostile HTTP client (part of the hostile-client suite, `make test-all`; loopback only).

A real daemon (worker doubles) and a real HMI; every case asserts that the cell did not move (no
command reached it: the daemon stays Stopped) and that the HMI still answers.
"""

from __future__ import annotations

import http.client
import json
import logging
import socket
import threading
import time
from collections.abc import Iterator

import pytest

from cellctl.hmi.server import Hmi, HmiServer
from tests.hmi.conftest import PASSWORDS, Client, hmi_config, wait_reachable

pytestmark = pytest.mark.slow


@pytest.fixture
def hostile(cfg, cell, clock) -> Iterator[tuple[Hmi, Client]]:
    h = Hmi(cfg, hmi_config(header_timeout_s=2.0, keepalive_s=1), clock)
    server = HmiServer(h).start()
    c = Client(h.hcfg.host, h.hcfg.port)
    wait_reachable(c)
    yield h, c
    server.stop()
    h.close()


def _unmoved(cell, c: Client) -> None:
    assert cell.supervisor.top_state == "Stopped"
    assert c.get("/api/status").status == 200


def _raw(h: Hmi, data: bytes, source: str = "127.0.0.1") -> bytes:
    with socket.create_connection((h.hcfg.host, h.hcfg.port), timeout=10, source_address=(source, 0)) as s:
        s.sendall(data)
        out = b""
        while chunk := s.recv(65536):
            out += chunk
            if b"\r\n\r\n" in out and len(out) > out.index(b"\r\n\r\n") + 4:
                break
        return out


def test_csrf_and_origins(cell, hostile) -> None:
    h, c = hostile
    assert c.login("alice").status == 200
    other = Client(c.host, c.port)
    assert other.login("bob").status == 200
    cases = [
        ({}, "no CSRF token"),
        ({"X-CSRF-Token": "x" * 43}, "a wrong token"),
        ({"X-CSRF-Token": other.csrf or ""}, "another session's token"),
        ({"X-CSRF-Token": c.csrf or "", "Origin": "http://evil.example"}, "another origin"),
        ({"X-CSRF-Token": c.csrf or "", "Sec-Fetch-Site": "cross-site"}, "a cross-site fetch"),
        ({"X-CSRF-Token": c.csrf or "", "Host": "evil.example", "Origin": "http://evil.example"}, "DNS rebinding"),
        ({"X-CSRF-Token": c.csrf or "", "Origin": "null"}, "an opaque origin"),
    ]
    for i, (headers, what) in enumerate(cases):
        r = c.request("POST", "/api/cmd", {"command": "reset", "nonce": f"hostile-nonce-{i:04d}"}, headers)
        assert r.status in (400, 403) and set(r.json()) == {"error"}, (what, r.status, r.body)
    for body in ({"cntrl_cmd": "1"}, {"cntrl_cmd": True}, {"command": 1}, {"command": "reset", "extra": 1}):
        assert c.post("/api/cmd", body).status == 422, body
    _unmoved(cell, c)


def test_sizes(cell, hostile) -> None:
    h, c = hostile
    assert c.get("/api/cycles?outcome=" + "a" * 4000).status == 414
    head = b"POST /api/login HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
    assert b" 413 " in _raw(h, head + b"Content-Length: 2000000\r\n\r\n{")
    assert b" 411 " in _raw(h, head + b"Transfer-Encoding: chunked\r\n\r\n5\r\nhello\r\n0\r\n\r\n")
    big = b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: " + b"a" * 100_000 + b"\r\n\r\n"
    assert b" 431 " in _raw(h, big) or b" 400 " in _raw(h, big)
    assert b" 400 " in _raw(h, b"\x16\x03\x01\x02\x00garbage-tls-hello\r\n\r\n")
    for path in ("/api/cycles?before=99999999999999999999999", "/api/cycles?limit=100000000000000000000"):
        assert c.get(path).status in (400, 422), path
    _unmoved(cell, c)


def test_traversal(cell, cfg, hostile) -> None:
    h, c = hostile
    root = str(cfg.path(cfg.recording.dir).parent)
    for path in (
        "/static/..%2f..%2f..%2fetc%2fpasswd",
        "/static/%2e%2e/%2e%2e/server.py",
        "/api/cycles/..%2F..%2Fetc%2Fpasswd/log",
        "/api/cycles/%2e%2e/log",
        "/api/cycles/....//....//etc/passwd/images/0",
        "/../../etc/passwd",
        "/api/cycles/" + "a" * 5000 + "/log",
    ):
        r = c.get(path)
        assert r.status in (400, 404, 414) and b"root:" not in r.body and root not in r.body.decode(), (path, r.body)
        assert set(r.json()) == {"error"}, path
    _unmoved(cell, c)


def test_slow_clients(cell, hostile) -> None:
    h, c = hostile
    socks = [socket.create_connection((h.hcfg.host, h.hcfg.port)) for _ in range(20)]
    stop = threading.Event()

    def trickle(s: socket.socket) -> None:
        s.sendall(b"POST /api/login HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 100\r\n\r\n")
        while not stop.wait(0.2):
            try:
                s.sendall(b"{")
            except OSError:
                return

    threads = [threading.Thread(target=trickle, args=(s,), daemon=True) for s in socks[:10]]  # 10 idle, 10 slow
    for t in threads:
        t.start()
    t0 = time.monotonic()
    assert c.get("/api/status").status == 200  # served while they hang on
    closed = 0
    for s in socks:
        s.settimeout(max(0.1, t0 + 6 - time.monotonic()))
        try:
            closed += s.recv(1) == b""
        except (TimeoutError, OSError):
            continue  # still open: counted as not closed
    stop.set()
    for s in socks:
        s.close()
    assert closed == 20 and time.monotonic() - t0 < 6, closed
    _unmoved(cell, c)


def test_brute_force(cell, hostile, caplog: pytest.LogCaptureFixture) -> None:
    h, c = hostile
    codes: dict[int, int] = {}
    t0 = time.monotonic()
    with caplog.at_level(logging.WARNING):
        for i in range(300):
            conn = http.client.HTTPConnection(h.hcfg.host, h.hcfg.port, timeout=10, source_address=("127.0.0.2", 0))
            conn.request("POST", "/api/login", json.dumps({"user": "alice", "password": f"guess-{i:04d}"}),
                         {"Content-Type": "application/json"})  # fmt: skip
            status = conn.getresponse().status
            conn.close()
            codes[status] = codes.get(status, 0) + 1
    elapsed = time.monotonic() - t0
    lines = [r for r in caplog.records if r.name.startswith("cellctl")]
    assert codes.get(200, 0) == 0 and codes.get(401, 0) == h.hcfg.login.pair_free, codes
    assert len(lines) <= 20, [r.getMessage() for r in lines]
    t = time.perf_counter()
    assert Client(c.host, c.port).login("alice", PASSWORDS["alice"]).status == 200  # the owner, from 127.0.0.1
    print(f"HMI: 300 guesses in {elapsed:.1f} s -> {codes}; {len(lines)} log lines; owner in "
          f"{(time.perf_counter() - t) * 1000:.0f} ms")  # fmt: skip
    _unmoved(cell, c)
