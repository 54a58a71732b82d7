"""Operator review over the REST API: roles, the audit ledger, bank growth, release gating.

A real daemon with worker doubles over real Zenoh: view 0 dirty, view 1 clean, view 2 clean but
uncertain (tests/hmi/test_heatmap.py), so the cycle holds one dirty and one uncertain view.
"""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor

from cellctl.cli import main
from cellctl.recording.audit import verify_audit
from cellctl.review import LEDGER_NAME
from tests.hmi.conftest import PASSWORDS, Client, wait_reachable
from tests.hmi.test_heatmap import _HeatCell


def run_review_cycle(cfg, client: Client, doubles: type[_HeatCell] = _HeatCell) -> str:
    """One completed cycle with a dirty view (view 0) and an uncertain one (view 2); its id."""
    wait_reachable(client)
    op = Client(client.host, client.port)
    assert op.login("alice", PASSWORDS["alice"]).status == 200
    with doubles(cfg):
        assert op.cmd("reset").status == 200
        op.wait_state("Idle")
        assert op.cmd("start").status == 200
        op.wait_state("Complete")
    return client.get("/api/cycles").json()["cycles"][0]["cycle_id"]


def _as(client: Client, user: str) -> Client:
    c = Client(client.host, client.port)
    assert c.login(user, PASSWORDS[user]).status == 200
    return c


def test_review_roles_ledger_bank_and_release(cfg, cell, hmi, client: Client, capsys) -> None:
    cid = run_review_cycle(cfg, client)
    items = client.get("/api/review/queue").json()["items"]
    rec = client.get(f"/api/cycles/{cid}/record").json()
    dv, cv, uv = (i["image"] for i in rec["images"])  # the views' images in the log (after identification's)
    assert [(i["image"], i["why"], i["surface"], i["decision"]) for i in items] == [
        (dv, "dirty", cfg.planner.surface, None),
        (uv, "uncertain", cfg.planner.surface, None),
    ]
    assert items[0]["heatmap"] and items[0]["reference"] is None and items[0]["bin_picture"]
    gate = client.get(f"/api/cycles/{cid}/release").json()
    assert gate["state"] == "review_required" and gate["open_uncertain"] == [uv] and gate["verdict"] == "dirty"
    assert client.get(f"/api/cycles/{cid}/record").json()["release"]["state"] == "review_required"

    # who may review: nobody logged out, not a viewer, not without the CSRF token; nothing recorded
    body = {"label": "clean", "reason": "a reflection of the arm"}
    assert client.post(f"/api/review/items/{cid}/{uv}", body).status == 401
    vic = _as(client, "vic")
    r = vic.post(f"/api/review/items/{cid}/{uv}", body)
    assert r.status == 403 and "'viewer'" in r.json()["error"] and set(r.json()) == {"error"}
    alice = _as(client, "alice")
    assert alice.post(f"/api/review/items/{cid}/{uv}", body, csrf=False).status == 403
    assert vic.post(f"/api/cycles/{cid}/release", {}).status == 403
    ledger = cfg.path(cfg.recording.dir) / LEDGER_NAME
    assert not ledger.exists()
    # a malformed decision, a view that is not in the queue, and the gate: one error shape each
    for path, b, code in ((f"/api/review/items/{cid}/{uv}", {"label": "maybe", "reason": "x y z"}, 422),
                          (f"/api/review/items/{cid}/{uv}", {"label": "clean", "reason": ""}, 422),
                          (f"/api/review/items/{cid}/{cv}", body, 404),
                          (f"/api/cycles/{cid}/release", {}, 409)):  # fmt: skip
        r = alice.post(path, b)
        assert r.status == code and set(r.json()) == {"error"}, (path, r.status, r.body)
    assert f"images [{uv}]" in alice.post(f"/api/cycles/{cid}/release", {}).json()["error"]

    # the operator confirms the uncertain view clean: ledger (user, time), bank +1 clean
    r = alice.post(f"/api/review/items/{cid}/{uv}", body)
    assert r.status == 200, r.body
    out = r.json()
    assert out["decision"]["user"] == "alice" and out["decision"]["label"] == "clean"
    assert out["bank"]["counts"] == {"clean": 1, "dirty": 0} and out["release"]["state"] == "ready"
    assert alice.post(f"/api/review/items/{cid}/{uv}", {**body, "label": "dirty"}).status == 409  # decided once
    # qa confirms the dirty view dirty: a labelled training example
    carol = _as(client, "carol")
    r = carol.post(f"/api/review/items/{cid}/{dv}", {"label": "dirty", "reason": "powder on the seam"})
    assert r.status == 200 and r.json()["bank"]["counts"] == {"clean": 1, "dirty": 1}, r.body
    assert carol.cmd("reset").status == 403  # qa reviews, it does not command the cell

    entries = [json.loads(x) for x in ledger.read_text().splitlines()]
    assert [(e["kind"], e["user"], e["role"], e["image"], e["label"]) for e in entries] == [
        ("decision", "alice", "operator", uv, "clean"),
        ("decision", "carol", "qa", dv, "dirty"),
    ]
    assert all(e["time"] and e["cycle_row_hash"] and len(e["image_sha256"]) == 64 for e in entries)
    bank = client.get("/api/review/bank").json()
    assert bank["counts"] == {cfg.planner.surface: {"clean": 1, "dirty": 1}} and bank["ledger"]["entries"] == 2
    manifest = json.loads((cfg.path(cfg.recording.dir) / "review" / "manifest.json").read_text())
    clean = next(e for e in manifest["entries"] if e["label"] == "clean")
    assert (clean["cycle_id"], clean["image"], clean["user"]) == (cid, uv, "alice")
    assert clean["decision_hash"] == entries[0]["entry_hash"]

    # released by review: the reviewed verdict, in the ledger, on the record; closed to later decisions
    r = carol.post(f"/api/cycles/{cid}/release", {"reason": "seam re-washed next"})
    assert r.status == 200, r.body
    rel = r.json()
    assert rel["state"] == "released" and rel["released_verdict"] == "dirty" and rel["released_by"] == "carol"
    assert client.get(f"/api/cycles/{cid}/record").json()["release"]["state"] == "released"
    assert carol.post(f"/api/cycles/{cid}/release", {}).status == 409
    assert client.get("/api/review/queue").json()["items"] == []
    assert len(client.get("/api/review/queue?state=decided").json()["items"]) == 2

    # the audit checks the ledger: intact, then an edited decision is found
    report = client.get("/api/audit").json()
    assert report["ok"], report["findings"]
    sets = [f"recording.index={cfg.path(cfg.recording.index)}", f"recording.dir={cfg.path(cfg.recording.dir)}"]
    assert main(["audit", "head", "--json", "--set", sets[0], "--set", sets[1]]) == 0
    head = json.loads(capsys.readouterr().out)["reviews"]
    assert head["entries"] == 3 and head["entry_hash"] == client.get("/api/review/bank").json()["ledger"]["entry_hash"]
    lines = ledger.read_text().splitlines()
    forged = json.loads(lines[1])
    forged["label"] = "clean"
    ledger.write_text("\n".join([lines[0], json.dumps(forged), lines[2]]) + "\n")
    found = verify_audit(cfg.path(cfg.recording.index), cfg.path(cfg.recording.dir))
    assert [f.kind.value for f in found.tampering] == ["review_edited"]
    journal = hmi.journal_path.read_text()
    assert '"kind":"review"' in journal and '"kind":"release"' in journal


def test_without_gating_a_verdict_stands_released(cfg, cell, hmi, client: Client) -> None:
    hmi.cfg.review.require_for_uncertain = False
    cid = run_review_cycle(cfg, client)
    st = client.get(f"/api/cycles/{cid}/release").json()
    assert st["state"] == "auto" and st["released_verdict"] == "dirty" and st["uncertain_views"] == 1
    r = _as(client, "alice").post(f"/api/cycles/{cid}/release", {})
    assert r.status == 409 and "stands released" in r.json()["error"]

    # two reviewers answer the same view at once: one decision is recorded, the other is refused
    uv = next(i["image"] for i in client.get("/api/review/queue").json()["items"] if i["uncertain"])
    people = [_as(client, "alice"), _as(client, "carol")]
    with ThreadPoolExecutor(2) as pool:
        codes = sorted(pool.map(lambda c: c.post(f"/api/review/items/{cid}/{uv}", {"label": "clean",
                                                 "reason": "seen at once"}).status, people))  # fmt: skip
    assert codes == [200, 409]
    assert len((cfg.path(cfg.recording.dir) / LEDGER_NAME).read_text().splitlines()) == 1
