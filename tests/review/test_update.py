"""``cellctl detector update``: re-enrollment from the confirmed-clean views of the review bank."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cellctl.classify.site import site_dataset
from cellctl.cli import main
from cellctl.config import load_config
from cellctl.review import open_bank


def _bank_of_site_views(tmp_path: Path, n_clean: int, n_dirty: int) -> list[str]:
    """A review bank holding ``n_clean`` confirmed-clean and ``n_dirty`` confirmed-dirty unseen-site views."""
    sets = ["--set", f"recording.dir={tmp_path / 'logs'}", "--set", f"recording.index={tmp_path / 'logs' / 'c.db'}"]
    cfg = load_config(None, [s for s in sets if s != "--set"])
    site_dataset(tmp_path / "site", "external", n_clean, n_dirty, seed=5)
    bank = open_bank(cfg)
    for label in ("clean", "dirty"):
        for i, p in enumerate(sorted((tmp_path / "site" / "external" / label).glob("*.png"))):
            prov = {"cycle_id": f"20261204T1200{i:02d}-000-{i}", "image": 3, "user": "alice", "reason": "seen"}
            bank.add("external", label, p.read_bytes(), "png", prov)  # type: ignore[arg-type]
    return sets


def test_too_few_confirmed_clean_views_are_refused_in_one_line(tmp_path: Path, capsys) -> None:
    sets = _bank_of_site_views(tmp_path, 3, 0)
    assert main(["detector", "update", "--surface", "external", *sets]) == 2
    err = capsys.readouterr().err
    assert "holds 3 confirmed-clean external view(s)" in err and "at least 10" in err


@pytest.mark.slow  # 332 s at load 36 on the 2 shared cores (enrollment of 20 views + a held-out set)
def test_update_reenrolls_from_the_bank_and_reports_how_the_decision_moved(tmp_path: Path, capsys) -> None:
    # 20 views: site-scaled enrollment refuses 12 views of this steel (7 of 35 synthetic dirty views would pass)
    sets = _bank_of_site_views(tmp_path, 20, 2)
    out = tmp_path / "ext.enrolled.pt"
    rc = main(["detector", "update", "--surface", "external", "--out", str(out), "--held-out", "4", *sets])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    rep = json.loads(cap.out.splitlines()[-1])
    assert out.is_file() and rep["after"]["model_id"].startswith("external-enrolled-")
    assert rep["bank"]["clean"] == 20 and rep["bank"]["dirty"] == 2
    assert rep["before"]["model_id"].startswith("external-detect-")
    for side in ("before", "after"):
        assert rep[side]["bank_clean"]["n"] == 20 and rep[side]["held_out_clean"]["n"] == 4
        assert rep[side]["held_out_dirty"]["n"] == 4 and "false_clean" in rep[side]["held_out_dirty"]
    # the site's own confirmed-clean views: no more false alarms after than before
    assert rep["after"]["bank_clean"]["false_dirty"] <= rep["before"]["bank_clean"]["false_dirty"]
    assert rep["card"]["clean"] >= 5 and rep["before"]["threshold"] != rep["after"]["threshold"]


@pytest.mark.parametrize("bad", ["--held-out=0", "--held-out=1001"])
def test_a_held_out_size_out_of_range_is_refused(bad: str, capsys) -> None:
    assert main(["detector", "update", "--surface", "external", bad]) == 2
    assert "--held-out" in capsys.readouterr().err
