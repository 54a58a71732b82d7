"""HMI edges a hostile client pokes at: login back-off, proxies, Host, slow clients, strict types, errors.

A real HMI server on loopback, no daemon (none of these need the cell: they are refused before it).
"""

from __future__ import annotations

import http.client
import json
import socket
import time
from collections.abc import Iterator

import pytest

from cellctl.hmi.server import Hmi, HmiServer
from tests.hmi.conftest import Client, hmi_config


@pytest.fixture
def edge(cfg, clock) -> Iterator[Hmi]:
    h = Hmi(cfg, hmi_config(header_timeout_s=1.0, keepalive_s=1), clock)
    server = HmiServer(h).start()
    yield h
    server.stop()
    h.close()


def _client(h: Hmi) -> Client:
    return Client(h.hcfg.host, h.hcfg.port)


def _login_from(h: Hmi, source: str, user: str, password: str, headers: dict[str, str] | None = None) -> int:
    conn = http.client.HTTPConnection(h.hcfg.host, h.hcfg.port, timeout=10, source_address=(source, 0))
    conn.request("POST", "/api/login", json.dumps({"user": user, "password": password}),
                 {"Content-Type": "application/json", **(headers or {})})  # fmt: skip
    status = conn.getresponse().status
    conn.close()
    return status


def test_a_guesser_slows_only_its_own_pair_and_loosely_its_address(edge: Hmi, clock) -> None:
    c = _client(edge)
    for _ in range(edge.hcfg.login.pair_free):
        assert c.login("alice", "guess-guess").status == 401
    assert c.login("alice").status == 429
    assert _login_from(edge, "127.0.0.2", "alice", "alice-password-1") == 200  # the owner, elsewhere: at once
    assert _client(edge).login("bob").status == 200  # another user at the guesser's address
    for i in range(edge.hcfg.login.address_free):  # spraying names from one address
        c.login(f"user{i}", "guess-guess")
    r = _client(edge).login("bob")
    assert r.status == 429 and 0 < int(r.headers["retry-after"]) <= edge.hcfg.login.address_max_s
    clock.t += edge.hcfg.login.address_max_s
    assert _client(edge).login("bob").status == 200  # never locked out for good


def test_x_forwarded_for_from_loopback_is_not_believed(edge: Hmi) -> None:
    for i in range(edge.hcfg.login.pair_free):  # a fresh spoofed address per guess would dodge the pair back-off
        assert _login_from(edge, "127.0.0.1", "alice", "guess-guess", {"X-Forwarded-For": f"127.0.9.{i}"}) == 401
    assert _login_from(edge, "127.0.0.1", "alice", "alice-password-1", {"X-Forwarded-For": "127.0.9.99"}) == 429
    journal = edge.journal_path.read_text()
    assert '"client":"127.0.0.1"' in journal and "127.0.9." not in journal


def test_host_must_be_one_of_the_hmis_names(edge: Hmi) -> None:
    c = _client(edge)
    r = c.request("GET", "/api/status", headers={"Host": f"evil.example:{edge.hcfg.port}"})
    assert r.status == 400 and "evil.example" in r.json()["error"]
    rebound = {"Host": "evil.example", "Origin": "http://evil.example"}  # DNS rebinding passes the Origin check
    r = c.request("POST", "/api/login", {"user": "alice", "password": "alice-password-1"}, rebound)
    assert r.status == 400 and not edge.sessions._sessions
    assert c.request("GET", "/api/status", headers={"Host": f"localhost:{edge.hcfg.port}"}).status in (200, 503)


@pytest.mark.parametrize("value", ["1", True, 1.0, [1]])
def test_cntrl_cmd_takes_integers_only(edge: Hmi, value: object) -> None:
    c = _client(edge)
    assert c.login("alice").status == 200
    r = c.post("/api/cmd", {"cntrl_cmd": value})
    assert r.status == 422 and "cntrl_cmd" in r.json()["error"], r.body


def test_query_and_path_parameters_are_bounded_and_errors_have_one_shape(edge: Hmi, cfg) -> None:
    c = _client(edge)
    for path in ("/api/cycles?before=99999999999999999999999", "/api/cycles?before=-1", "/api/cycles?before=x",
                 "/api/cycles/x/images/99999999999999999999", "/api/events?limit=99999999999999999999"):  # fmt: skip
        r = c.get(path)
        assert r.status == 400 and set(r.json()) == {"error"}, (path, r.status, r.body)
    r = c.request("GET", "/api/status", headers={"X-Big": "a" * 20000})  # a whole head, over the 16 KiB limit
    assert r.status == 431 and set(r.json()) == {"error"}, r.body
    r = c.request("PUT", "/api/status", {})
    assert r.status == 405 and set(r.json()) == {"error"}, r.body
    r = c.get("/api/cycles/20260101T000000-000-1")
    root = str(cfg.path(cfg.recording.dir).parent)
    assert r.status == 404 and set(r.json()) == {"error"} and root not in r.body.decode(), r.body


def _closed_within(sock: socket.socket, seconds: float, trickle: bytes = b"") -> float:
    """Seconds until the server closed ``sock`` (sending ``trickle`` a byte per 0.2 s meanwhile)."""
    t0 = time.monotonic()
    sock.settimeout(0.2)
    for i in range(int(seconds / 0.2)):
        if trickle:
            try:
                sock.send(trickle[i % len(trickle) : i % len(trickle) + 1])
            except OSError:
                return time.monotonic() - t0
        try:
            if sock.recv(1024) == b"":
                return time.monotonic() - t0
        except TimeoutError:
            continue
        except OSError:
            return time.monotonic() - t0
    return float("inf")


def test_slow_and_idle_connections_are_closed(edge: Hmi) -> None:
    addr = (edge.hcfg.host, edge.hcfg.port)
    with socket.create_connection(addr) as idle, socket.create_connection(addr) as slow:
        slow.send(b"GET /api/status HTTP/1.1\r\n")
        t_slow = _closed_within(slow, 6.0, trickle=b"X-Padding: aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa")
        t_idle = _closed_within(idle, 6.0)
    assert t_slow < 3.0 and t_idle < 3.0, (t_slow, t_idle)
    assert _client(edge).get("/api/status").status in (200, 503)  # the server itself is fine
