"""The HMI and its REST API show an `incomplete` verdict with each surface's seen share (issue 35)."""

from __future__ import annotations

from tests.fakes.workers import FakeCell
from tests.hmi.conftest import Client, wait_reachable


def test_an_incomplete_cycle_is_listed_filtered_and_shown_with_its_fractions(cfg, cell, hmi, client: Client) -> None:
    # the conftest's single-station doubles see six faces of one surface: the shipped minimum makes it partial
    cfg.classifier.verdict.min_seen_fraction = {"external": 0.6, "internal": 0.6}
    wait_reachable(client)
    client.login("alice")
    with FakeCell(cfg):
        assert client.cmd("reset").status == 200
        client.wait_state("Idle")
        assert client.cmd("start").status == 200
        st = client.wait_state("Complete")
    (row,) = client.get("/api/cycles?verdict=incomplete").json()["cycles"]
    assert row["outcome"] == "completed" and row["reason"].startswith("incomplete: no dirt seen, but external")
    assert client.get("/api/cycles?verdict=clean").json()["cycles"] == []
    res = client.get(f"/api/cycles/{row['cycle_id']}").json()
    assert res["verdict"] == "incomplete" and res["coverage_by_surface"]["internal"] == 0.0
    assert res["min_seen_fraction"] == {"external": 0.6, "internal": 0.6}
    last = client.get("/api/status").json()["status"]["admin"]["last_cycle"]
    assert st["state"] == "Complete" and last["verdict"] == "incomplete"
    assert last["coverage_by_surface"] == res["coverage_by_surface"]
    live = client.get("/api/live").json()["live"]
    assert live["verdict"] == "incomplete" and live["coverage_by_surface"] == res["coverage_by_surface"]
    # the pages know the value: the history filter offers it, the script draws it with its fractions
    assert "<option>incomplete</option>" in client.get("/history").body.decode()
    js = client.get("/static/app.js").body.decode()
    assert "verdict-incomplete" in js and "seenText(" in js
