"""The HMI's REST API against a real daemon over real Zenoh (worker doubles), through real HTTP."""

from __future__ import annotations

import datetime as dt
import json
import sqlite3
import time

import pytest

from cellctl.recording.replay import read_cycle
from tests.fakes.workers import FakeCell
from tests.hmi.conftest import Client, wait_reachable


def test_reading_needs_no_login_but_commands_do(cell, hmi, client: Client) -> None:
    wait_reachable(client)
    st = client.get("/api/status").json()
    assert st["reachable"] and st["status"]["state"] == "Stopped"
    assert client.get("/").status == 200 and b"PackML" in client.get("/").body
    r = client.cmd("reset")
    assert r.status == 401 and "log in" in r.json()["error"]
    assert cell.supervisor.top_state == "Stopped"


def test_login_command_csrf_and_replay(cell, hmi, client: Client) -> None:
    wait_reachable(client)
    assert client.login("alice", "wrong-password").status == 401
    r = client.login("alice")
    assert r.status == 200 and r.json()["role"] == "operator"
    cookie = client.set_cookies[-1]
    assert "HttpOnly" in cookie and "SameSite=strict" in cookie.replace("Strict", "strict")

    # forged: no CSRF token, or a wrong one, or from another origin -> refused, nothing changes
    assert client.post("/api/cmd", {"command": "reset"}, csrf=False).status == 403
    bad = client.request("POST", "/api/cmd", {"command": "reset", "nonce": "n" * 20}, {"X-CSRF-Token": "x" * 43})
    assert bad.status == 403 and "CSRF" in bad.json()["error"]
    evil = client.request(
        "POST",
        "/api/cmd",
        {"command": "reset", "nonce": "e" * 20},
        {"X-CSRF-Token": client.csrf, "Origin": "http://evil.example"},
    )
    assert evil.status == 403 and "origin" in evil.json()["error"]
    assert cell.supervisor.top_state == "Stopped"

    r = client.post("/api/cmd", {"command": "reset", "nonce": "once-only-nonce-0001"})
    assert r.status == 200, r.body
    ack = r.json()["ack"]
    assert ack["accepted"] and ack["user"] == "hmi:alice" and ack["request_id"].startswith("hmi:alice:")
    client.wait_state("Idle")
    replay = client.post("/api/cmd", {"command": "reset", "nonce": "once-only-nonce-0001"})
    assert replay.status == 409 and "replayed" in replay.json()["error"]

    # a command the state does not allow: the daemon's reason, an HTTP error, no state change
    r = client.cmd("hold")
    assert r.status == 409 and "not allowed in state 'Idle'" in r.json()["error"]
    assert cell.supervisor.top_state == "Idle"
    r = client.cmd("jump")
    assert r.status == 422 and "command" in r.json()["error"]
    # the operator may not change the unit mode; maintenance may (TR88: in Idle)
    r = client.post("/api/cmd", {"unit_mode": "maintenance"})
    assert r.status == 403 and "maintenance role" in r.json()["error"]
    bob = Client(client.host, client.port)
    bob.login("bob")
    r = bob.post("/api/cmd", {"unit_mode": "maintenance"})
    assert r.status == 200 and r.json()["ack"]["unit_mode"] == "maintenance", r.body
    # logged out: the session is gone, its CSRF token with it
    assert client.post("/api/logout", {}, nonce=False).status == 200
    assert client.cmd("stop").status == 401
    journal = hmi.journal_path.read_text()
    assert '"user":"alice"' in journal and '"command":"reset"' in journal


def test_a_cycle_from_the_hmi_lands_in_the_records(cfg, cell, hmi, client: Client) -> None:
    wait_reachable(client)
    client.login("alice")
    with FakeCell(cfg, dirty_viewpoints={1}):
        assert client.cmd("reset").status == 200
        client.wait_state("Idle")
        assert client.cmd("start").status == 200
        client.wait_state("Complete")
    rows = client.get("/api/cycles").json()["cycles"]
    assert len(rows) == 1 and rows[0]["outcome"] == "completed" and rows[0]["verdict"] == "dirty"
    assert rows[0]["log_path"] is None  # host paths are not published
    cid = rows[0]["cycle_id"]
    res = client.get(f"/api/cycles/{cid}").json()
    assert res["type"] == "cellctl/CycleResult" and res["verdict"] == "dirty"
    # the Start command is in the cycle log with the HMI user (the audit trail)
    path = cfg.path(res["log"])
    cmds = [m.json() for m in read_cycle(path).on(f"cell/{cfg.cell_id}/cmd")]
    assert any(c.get("command") == "start" and c.get("user") == "hmi:alice" for c in cmds), cmds
    # the record page: per-view images with their scores, audit status
    rec = client.get(f"/api/cycles/{cid}/record").json()
    assert [i["label"] for i in rec["images"]] == ["clean", "dirty", "clean"]
    assert rec["audit"]["status"] == "ok" and rec["audit"]["head"]["seq"] == rows[0]["seq"]
    img = client.get(f"/api/cycles/{cid}/images/{rec['images'][1]['image']}")
    assert img.status == 200 and img.body[:4] == b"\x89PNG"
    png = client.get(f"/api/cycles/{cid}/dirt_map.png")
    assert png.status == 200 and png.body[:4] == b"\x89PNG"
    log = client.get(f"/api/cycles/{cid}/log")
    assert log.status == 200 and log.body == path.read_bytes()
    audit = client.get("/api/audit").json()
    assert audit["ok"] and audit["head"]["seq"] == rows[0]["seq"]
    # filters
    assert client.get("/api/cycles?verdict=clean").json()["cycles"] == []
    assert len(client.get("/api/cycles?outcome=completed&bin=case_study").json()["cycles"]) == 1
    assert client.get("/api/cycles?until=2000-01-01").json()["cycles"] == []
    # the live view followed the cycle to its end
    live = client.get("/api/live").json()["live"]
    assert live["cycle_id"] == cid and live["outcome"] == "completed" and live["n_viewpoints"] == 3
    assert [v["label"] for v in live["verdicts"]] == ["clean", "dirty", "clean"]
    assert client.get("/api/live/image").body[:4] == b"\x89PNG"


def test_bad_requests_get_clear_errors_and_nothing_outside_logs(cfg, cell, hmi, client: Client) -> None:
    wait_reachable(client)
    r = client.get("/api/cycles/20990101T000000-000-1")
    assert r.status == 404 and "not in the cycle index" in r.json()["error"]
    for path in ("/api/cycles/..%2F..%2Fetc%2Fpasswd/log", "/api/cycles/../../etc/passwd", "/static/..%2Fserver.py"):
        r = client.get(path)
        assert r.status == 404, (path, r.status)
        assert b"root:" not in r.body and b"import" not in r.body
    r = client.get("/api/cycles/" + "%2E%2E" + "/log")
    assert r.status == 404
    r = client.get("/api/cycles?since=" + "x" * 5000)
    assert r.status == 414 and "query string" in r.json()["error"]
    r = client.get("/api/cycles?outcome=exploded")
    assert r.status == 422 and "expected one of" in r.json()["error"]
    r = client.get("/api/cycles?since=yesterday")
    assert r.status == 422 and "YYYY-MM-DD" in r.json()["error"]
    r = client.request("POST", "/api/login", b"x" * 20000)
    assert r.status == 413
    assert client.request("POST", "/api/login", b"{not json").status == 422

    # an index row whose log path points outside the logs folder: never served
    with FakeCell(cfg):
        client.login("alice")
        client.cmd("reset")
        client.wait_state("Idle")
        client.cmd("start")
        client.wait_state("Complete")
    cid = client.get("/api/cycles").json()["cycles"][0]["cycle_id"]
    db = sqlite3.connect(cfg.path(cfg.recording.index))
    db.execute("UPDATE cycles SET log_path = '/etc/passwd' WHERE cycle_id = ?", (cid,))
    db.commit()
    db.close()
    r = client.get(f"/api/cycles/{cid}/log")
    assert r.status == 404 and b"root:" not in r.body
    audit = client.get(f"/api/cycles/{cid}/record").json()["audit"]
    assert audit["status"] == "tamper" and "outside the logs folder" in " ".join(audit["findings"])
    assert "edited" in " ".join(audit["findings"])  # log_path is a chained field


def test_login_back_off_and_session_expiry(cell, hmi, client: Client, clock) -> None:
    for _ in range(hmi.hcfg.login.pair_free):
        assert client.login("alice", "guess-guess").status == 401
    r = client.login("alice")  # even the right password, until the back-off has passed
    assert r.status == 429 and "too many failed logins" in r.json()["error"] and int(r.headers["retry-after"]) > 0
    other = Client(client.host, client.port)
    assert other.login("bob").status == 200  # another user at the same address is not locked out by alice's guesser
    clock.t += hmi.hcfg.login.base_s
    assert client.login("alice").status == 200
    assert client.get("/api/session").json()["user"] == "alice"
    clock.t += hmi.hcfg.session_idle_s + 1
    r = client.cmd("reset")
    assert r.status == 401 and "expired" in r.json()["error"]
    assert cell.supervisor.top_state == "Stopped"


def test_daemon_down_shows_unreachable_and_recovers(cfg, hmi, client: Client) -> None:
    from cellctl.app import build_cell
    from cellctl.geometry.catalog import load_catalog
    from tests.fakes.workers import fake_identify

    r = client.get("/api/status")  # started before the daemon: unreachable, says so
    assert r.status == 503 and r.json()["reachable"] is False and r.json()["error"]
    ident = (fake_identify, load_catalog(cfg.path(cfg.catalog)))
    cell = build_cell(cfg, identification=ident)
    try:
        wait_reachable(client, 20)
        client.login("alice")
    finally:
        cell.close()
    deadline = time.monotonic() + 10
    while client.get("/api/status").status != 503:
        assert time.monotonic() < deadline, "HMI still claims the cell is reachable"
        time.sleep(0.2)
    r = client.cmd("reset")
    assert r.status == 503 and "unreachable" in r.json()["error"]
    cell = build_cell(cfg, identification=ident)
    try:
        wait_reachable(client, 30)  # recovers by itself
        assert client.cmd("reset").status == 200
    finally:
        cell.close()


def test_alarms_are_acknowledged_by_a_logged_in_user(cell, hmi, client: Client) -> None:
    wait_reachable(client)
    client.login("alice")
    client.cmd("reset")
    client.wait_state("Idle")
    client.cmd("start")  # no workers: the cycle aborts with an error -> an alarm
    client.wait_state("Aborted")
    deadline = time.monotonic() + 5
    while not client.get("/api/alarms").json()["alarms"]:
        assert time.monotonic() < deadline
        time.sleep(0.1)
    time.sleep(0.5)  # the event and the Status's last_error both arrive; they are one fault
    alarms = client.get("/api/alarms").json()["alarms"]
    assert len([a for a in alarms if a["level"] == "error"]) == 1, alarms
    alarm = alarms[0]
    assert alarm["acked_by"] is None and alarm["level"] in ("error", "fatal", "warning")
    anon = Client(client.host, client.port)
    assert anon.post(f"/api/alarms/{alarm['id']}/ack", {}).status == 401
    assert client.post(f"/api/alarms/{alarm['id']}/ack", {}, csrf=False).status == 403
    r = client.post(f"/api/alarms/{alarm['id']}/ack", {})
    assert r.status == 200 and r.json()["alarm"]["acked_by"] == "alice"
    assert client.post("/api/alarms/999999/ack", {}).status == 404
    assert any("acknowledged" in e["text"] for e in client.get("/api/events").json()["events"])


def test_openapi_schema_lists_the_api(hmi, client: Client) -> None:
    spec = client.get("/openapi.json").json()
    for path in ("/api/status", "/api/cmd", "/api/cycles", "/api/cycles/{cycle_id}", "/api/cycles/{cycle_id}/log",
                 "/api/audit"):  # fmt: skip
        assert path in spec["paths"], path
    assert client.get("/docs").status == 404  # the Swagger page would load a CDN


@pytest.mark.parametrize("path", ["/", "/live", "/history", "/events", "/login"])
def test_pages_load_only_local_assets(hmi, client: Client, path: str) -> None:
    r = client.get(path)
    assert r.status == 200 and "default-src 'self'" in r.headers["content-security-policy"]
    assert b"http://" not in r.body and b"https://" not in r.body


def test_live_foxglove_view_advertises_the_log_channels_and_the_scene(cfg, cell, clock) -> None:
    import json as _json

    import websocket

    from cellctl.hmi.config import FoxgloveConfig
    from cellctl.hmi.server import Hmi, HmiServer
    from tests.conftest import free_port
    from tests.hmi.conftest import hmi_config

    h = Hmi(cfg, hmi_config(foxglove=FoxgloveConfig(enabled=True, port=free_port())), clock)
    server = HmiServer(h).start()
    try:
        c = Client(h.hcfg.host, h.hcfg.port)
        wait_reachable(c)
        c.login("alice")
        with FakeCell(cfg):
            c.cmd("reset")
            c.wait_state("Idle")
            c.cmd("start")
            c.wait_state("Complete")
        time.sleep(0.6)  # the live watcher's next poll forwards the last messages
        ws = websocket.create_connection(
            f"ws://127.0.0.1:{h.foxglove.port}", subprotocols=["foxglove.sdk.v1"], timeout=5
        )
        topics: set[str] = set()
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and not {"/camera/image", "/hmi/scene"} <= topics:
            msg = ws.recv()
            if isinstance(msg, str):
                m = _json.loads(msg)
                if m.get("op") == "advertise":
                    topics |= {ch["topic"] for ch in m["channels"]}
        ws.close()
        assert {"/camera/image", "/camera/pose", "/hmi/scene", f"cell/{cfg.cell_id}/status"} <= topics, topics
        assert f"cell/{cfg.cell_id}/robot/move/request" in topics  # what only the log holds, not the bus
    finally:
        server.stop()
        h.close()


def test_the_event_stream_sends_updates_and_ends_with_its_client(cell, hmi, client: Client) -> None:
    import socket

    wait_reachable(client)
    socks = []
    for _ in range(3):
        s = socket.create_connection((client.host, client.port), timeout=5)
        s.sendall(b"GET /api/stream HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        data = b""
        while b"event: update" not in data:
            data += s.recv(65536)
        assert b'"reachable":true' in data and b"text/event-stream" in data
        socks.append(s)
    assert hmi.streams == 3
    for s in socks:
        s.close()
    deadline = time.monotonic() + 5
    while hmi.streams:  # a page closed is a generator gone, not one left polling forever
        assert time.monotonic() < deadline, f"{hmi.streams} streams still open"
        time.sleep(0.1)


def test_odd_tokens_and_bodies_are_refused_cleanly(cell, hmi, client: Client) -> None:
    client.login("alice")
    r = client.request("POST", "/api/cmd", {"command": "reset", "nonce": "n" * 20}, {"X-CSRF-Token": "é" * 10})
    assert r.status == 403  # a non-ASCII token is a wrong token, not a server error
    r = client.post("/api/cmd", {"command": "reset", "nonce": "../../etc"})
    assert r.status == 422 and "nonce" in r.json()["error"]
    r = client.request("POST", "/api/login", {"user": "alice"})
    assert r.status == 422 and "password" in r.json()["error"]
    r = client.post("/api/cmd", {"command": "reset", "user": "hmi:mallory"})
    assert r.status == 422 and "user" in r.json()["error"]  # the HMI sets who sent it, never the client
    assert cell.supervisor.top_state == "Stopped"


def test_hmi_commands_carry_the_hmis_stamp_and_the_supervisor_checks_it(cell, hmi, client: Client, monkeypatch) -> None:
    wait_reachable(client)
    assert client.login("alice").status == 200
    seen: list[dict] = []  # what reached the daemon, as it arrived
    real = cell.supervisor.apply_command
    monkeypatch.setattr(
        cell.supervisor, "apply_command", lambda payload: seen.append(json.loads(payload)) or real(payload)
    )
    r = client.cmd("reset")
    assert r.status == 200 and r.json()["ack"]["accepted"], r.body
    age = dt.datetime.now(dt.UTC) - dt.datetime.fromisoformat(seen[-1]["stamp"])
    assert abs(age.total_seconds()) < 30
    client.wait_state("Idle")
    # an HMI whose clock is an hour behind: its otherwise valid Stop is refused as stale, nothing moves
    hour_ago = (dt.datetime.now(dt.UTC) - dt.timedelta(hours=1)).isoformat()
    monkeypatch.setattr("cellctl.hmi.routes.cell.now_iso", lambda: hour_ago)
    r = client.cmd("stop")
    assert r.status == 409 and "s old" in r.json()["error"], r.body
    assert seen[-1]["stamp"] == hour_ago and cell.supervisor.top_state == "Idle"
