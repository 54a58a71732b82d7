"""The review ledger (hash chain anchored to the cycle index) and the bounded bank of reviewed views."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cellctl.errors import RecordingError
from cellctl.review import Ledger, ReviewBank, check_ledger

ROW = "a" * 64


def _ledger(tmp_path: Path) -> Ledger:
    led = Ledger(tmp_path / "reviews.jsonl")
    led.append("decision", "c1", ROW, "alice", "operator", image=2, label="clean", reason="a reflection")
    led.append("decision", "c1", ROW, "carol", "qa", image=0, label="dirty", reason="powder on the weld")
    led.append("release", "c1", ROW, "carol", "qa", verdict="dirty", reason="reviewed")
    return led


def test_the_ledger_chains_its_entries_and_names_user_and_time(tmp_path: Path) -> None:
    led = _ledger(tmp_path)
    es = led.entries()
    assert [e["seq"] for e in es] == [1, 2, 3] and es[1]["prev_hash"] == es[0]["entry_hash"]
    assert es[0]["user"] == "alice" and es[0]["role"] == "operator" and es[0]["time"].endswith("+00:00")
    assert check_ledger(led.path, {"c1": ROW}) == []
    assert led.head() == {"entries": 3, "seq": 3, "entry_hash": es[2]["entry_hash"]}


def test_an_edited_deleted_or_unanchored_entry_is_found(tmp_path: Path) -> None:
    led = _ledger(tmp_path)
    lines = led.path.read_text().splitlines()
    assert {p.kind for p in check_ledger(led.path, {"c1": "b" * 64})} == {"anchor"}  # the record changed later
    assert {p.kind for p in check_ledger(led.path, {})} == {"anchor"}  # the cycle's row is gone

    edited = json.loads(lines[1])
    edited["label"] = "clean"  # someone turns a confirmed-dirty view clean
    led.path.write_text("\n".join([lines[0], json.dumps(edited), lines[2]]) + "\n")
    found = check_ledger(led.path, {"c1": ROW})
    assert [(p.kind, p.seq) for p in found] == [("edited", 2)] and "carol" in found[0].message

    led.path.write_text("\n".join([lines[0], lines[2]]) + "\n")  # the decision deleted
    assert [(p.kind, p.seq) for p in check_ledger(led.path, {"c1": ROW})] == [("chain", 3)]
    led.path.write_text(lines[0] + "\nnot json\n")
    assert [p.kind for p in check_ledger(led.path, {"c1": ROW})] == ["unreadable"]


def test_the_bank_keeps_provenance_and_evicts_the_oldest_beyond_its_bound(tmp_path: Path) -> None:
    bank = ReviewBank(tmp_path / "bank", max_per_label=2)
    for i in range(3):
        out = bank.add("internal", "clean", b"png-%d" % i, "png", {"cycle_id": f"c{i}", "image": 4, "user": "alice"})
    assert out["evicted"] == ["internal/clean/c0-4.png"]
    assert not (tmp_path / "bank" / "internal/clean/c0-4.png").exists()
    bank.add("internal", "dirty", b"jpg", "jpeg", {"cycle_id": "c9", "image": 1, "user": "carol"})
    m = bank.manifest()
    assert [e["cycle_id"] for e in m["entries"]] == ["c1", "c2", "c9"]
    assert m["evicted"] == {"internal": {"clean": 1, "dirty": 0}} and bank.counts() == {
        "internal": {"clean": 2, "dirty": 1}
    }
    assert [p.name for p in bank.files("internal", "clean")] == ["c1-4.png", "c2-4.png"]
    (tmp_path / "bank" / "internal/clean/c2-4.png").write_bytes(b"other")
    with pytest.raises(RecordingError, match="changed since it was reviewed"):
        bank.files("internal", "clean")
    with pytest.raises(RecordingError, match="surface 'roof'"):
        bank.add("roof", "clean", b"x", "png", {"cycle_id": "c", "image": 0})


def test_the_review_config_refuses_unknown_keys_and_bounds_the_bank(tmp_path: Path) -> None:
    from cellctl.config import load_config
    from cellctl.errors import ConfigError
    from cellctl.review import bank_dir

    cfg = load_config(None, [f"recording.dir={tmp_path / 'logs'}"])
    assert cfg.review.require_for_uncertain and bank_dir(cfg) == tmp_path / "logs" / "review"
    with pytest.raises(ConfigError, match="require_for_uncertian"):
        load_config(None, ["review.require_for_uncertian=false"])
    with pytest.raises(ConfigError, match="max_per_label"):
        load_config(None, ["review.max_per_label=3"])
    with pytest.raises(ConfigError, match="require_for_uncertain"):
        load_config(None, ["review.require_for_uncertain=yes"])  # strict: only true/false
