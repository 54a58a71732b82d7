"""A real daemon (worker doubles over real Zenoh) and a real HMI server on loopback ports."""

from __future__ import annotations

import http.client
import json
import secrets
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest

from cellctl.hmi.auth import hash_password
from cellctl.hmi.config import HmiConfig, HmiUser
from cellctl.hmi.server import Hmi, HmiServer
from tests.conftest import free_port
from tests.supervisor.test_cycle_over_zenoh import cell  # noqa: F401 - the daemon fixture, shared

PASSWORDS = {
    "alice": "alice-password-1",
    "bob": "bob-password-22",
    "carol": "carol-password-3",
    "vic": "vic-password-44",
}
"""alice operator, bob maintenance, carol qa (reviews, no commands), vic viewer (reads only)."""


class FakeClock:
    """Monotonic seconds the test moves by hand (sessions, login limiter)."""

    def __init__(self) -> None:
        self.t = time.monotonic()

    def __call__(self) -> float:
        return self.t


@dataclass
class Reply:
    status: int
    headers: dict[str, str]
    body: bytes

    def json(self) -> Any:
        return json.loads(self.body)


@dataclass
class Client:
    """An HTTP client of the HMI that keeps its cookie (what a browser tab does)."""

    host: str
    port: int
    cookie: str | None = None
    csrf: str | None = None
    set_cookies: list[str] = field(default_factory=list)

    def request(self, method: str, path: str, body: Any = None, headers: dict[str, str] | None = None) -> Reply:
        conn = http.client.HTTPConnection(self.host, self.port, timeout=30)
        h = dict(headers or {})
        data = None
        if body is not None:
            data = body if isinstance(body, bytes) else json.dumps(body).encode()
            h.setdefault("Content-Type", "application/json")
        if self.cookie:
            h["Cookie"] = self.cookie
        conn.request(method, path, body=data, headers=h)
        r = conn.getresponse()
        out = Reply(r.status, {k.lower(): v for k, v in r.getheaders()}, r.read())
        for k, v in r.getheaders():
            if k.lower() == "set-cookie":
                self.set_cookies.append(v)
                name_value = v.split(";", 1)[0]
                self.cookie = None if name_value.endswith("=") or "Max-Age=0" in v else name_value
        conn.close()
        return out

    def get(self, path: str) -> Reply:
        return self.request("GET", path)

    def login(self, user: str, password: str | None = None) -> Reply:
        r = self.request("POST", "/api/login", {"user": user, "password": password or PASSWORDS[user]})
        if r.status == 200:
            self.csrf = r.json()["csrf"]
        return r

    def post(self, path: str, body: dict[str, Any], csrf: bool = True, nonce: bool = True) -> Reply:
        if nonce and "nonce" not in body:
            body = {**body, "nonce": secrets.token_urlsafe(18)}
        headers = {"X-CSRF-Token": self.csrf} if csrf and self.csrf else {}
        return self.request("POST", path, body, headers)

    def cmd(self, command: str, **extra: Any) -> Reply:
        return self.post("/api/cmd", {"command": command, **extra})

    def wait_state(self, state: str, timeout: float = 20.0) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        last = None
        while time.monotonic() < deadline:
            r = self.get("/api/status")
            last = r.json()
            if r.status == 200 and last["status"]["state"] == state:
                return last["status"]
            time.sleep(0.1)
        raise AssertionError(f"state {state!r} not reached in {timeout} s; last {last}")


def hmi_config(**kw: Any) -> HmiConfig:
    users = [
        HmiUser(name="alice", role="operator", password_hash=hash_password(PASSWORDS["alice"])),
        HmiUser(name="bob", role="maintenance", password_hash=hash_password(PASSWORDS["bob"])),
        HmiUser(name="carol", role="qa", password_hash=hash_password(PASSWORDS["carol"])),
        HmiUser(name="vic", role="viewer", password_hash=hash_password(PASSWORDS["vic"])),
    ]
    return HmiConfig(port=free_port(), users=users, stale_s=1.0, **kw)


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def hmi(cfg, clock) -> Iterator[Hmi]:
    h = Hmi(cfg, hmi_config(), clock)
    server = HmiServer(h).start()
    h.server = server  # type: ignore[attr-defined]
    yield h
    server.stop()
    h.close()


@pytest.fixture
def client(hmi) -> Client:
    return Client(hmi.hcfg.host, hmi.hcfg.port)


def wait_reachable(c: Client, timeout: float = 15.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if c.get("/api/status").status == 200:
            return
        time.sleep(0.1)
    raise AssertionError(f"HMI never saw the cell: {c.get('/api/status').json()}")
