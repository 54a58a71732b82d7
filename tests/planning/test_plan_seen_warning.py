"""A bin no plan sees enough of for a clean verdict says so when it is planned (issue 35, item 4)."""

from __future__ import annotations

import json

import pytest

from cellctl.planning.shapes import open_box_bin

pytestmark = pytest.mark.slow  # a whole-bin plan (~10 s CPU); tests/test_seen.py covers the rule itself


def test_plan_whole_warns_with_the_fractions_when_its_cycles_cannot_be_clean(tmp_path, capsys) -> None:
    from cellctl.cli import main

    mesh_file = tmp_path / "box.stl"
    open_box_bin((0.8, 0.6, 0.8), max_edge=0.1).to_trimesh().export(mesh_file)
    common = ["plan", "--mesh", str(mesh_file), "--whole", "--seed-pct", "3", "--json"]
    sets = ["planner.whole.candidates=4", "planner.whole.inner_candidates=0", f"planner.plans_dir={tmp_path / 'p'}"]
    # the whole surface of both: more than any plan of an open box on the floor sees (its bottom)
    sets.append("classifier.verdict.min_seen_fraction={external: 1.0, internal: 1.0}")
    assert main([*common, *[a for s in sets for a in ("--set", s)]]) == 0  # a warning, not an empty plan
    out = capsys.readouterr()
    j = json.loads(out.out)
    assert j["min_seen_fraction"] == {"external": 1.0, "internal": 1.0}
    seen = {k: v["area_fraction"] for k, v in j["surfaces"].items()}
    assert j["seen_warning"].startswith(f"this plan cannot certify the bin clean: external {seen['external']:.0%} seen")
    assert "needs 100%" in j["seen_warning"] and "no reachable camera pose sees more than" in j["seen_warning"]
    assert f"cellctl plan: warning: {j['seen_warning']}" in out.err
