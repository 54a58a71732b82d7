"""`cellctl demo`'s stories as data (cellctl/bench/demo/stories/*.yaml): the whole-bin dirty bin is a
wash-and-verify cycle unless `--no-wash`; a malformed story file is refused naming the key."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import get_args

import pytest

from cellctl.bench.demo.runner import STEPS, paths
from cellctl.bench.demo.stories import STORIES_DIR, StepName, Story, chosen, load_story_file, story_path
from cellctl.cli.demo import register, story_file_name
from cellctl.errors import ConfigError


def _stories(name: str, wash: bool) -> list[Story]:
    return load_story_file(story_path(name)).played(wash)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser()
    register(ap.add_subparsers())
    return ap


def test_the_default_demo_washes_and_no_wash_skips_it() -> None:
    ap = _parser()
    assert ap.parse_args(["demo"]).wash is True
    assert ap.parse_args(["demo", "--no-wash"]).wash is False
    assert story_file_name(ap.parse_args(["demo"])) == "whole_bin"
    assert story_file_name(ap.parse_args(["demo", "--single-station"])) == "single_station"
    with pytest.raises(ConfigError, match="--single-station and --stories wash_only"):
        story_file_name(ap.parse_args(["demo", "--single-station", "--stories", "wash_only"]))


def test_every_shipped_story_file_loads_and_names_only_steps_the_runner_has() -> None:
    assert set(get_args(StepName)) == set(STEPS)
    files = sorted(STORIES_DIR.glob("*.yaml"))
    assert {p.stem for p in files} >= {"whole_bin", "single_station", "wash_only"}
    for path in files:
        for story in load_story_file(path).stories:
            assert story.steps[:2] == ["scenario", "cycle"] and story.steps[-1] == "clear", (path, story.story)


def test_the_whole_bin_story_tells_dirty_and_washed_clean_in_one_cycle() -> None:
    plain, washed = _stories("whole_bin", wash=False), _stories("whole_bin", wash=True)
    assert all(s.start.get("mode") != "wash_and_verify" for s in plain)
    assert [s.start.get("mode") for s in washed].count("wash_and_verify") == 1
    # the wash cycle takes the plain dirty scan's place (its scan is the dirty verdict): no extra scan
    assert len(washed) == len(plain)
    (dirty,) = [s for s in plain if s.expect.verdict == "dirty"]
    (wash,) = [s for s in washed if s.start.get("mode")]
    assert washed.index(wash) == plain.index(dirty) and wash.scenario.dirty is True
    assert washed[-1].expect == plain[-1].expect


def test_the_scenarios_are_the_sim_requests_the_demo_always_sent() -> None:
    """Byte for byte the fields of the hard-coded stories before they were data (radians from degrees)."""
    home = (0.1, 0.2, 0.3, 0.4)
    new_bin, adjusted, wash, beyond = (s.scenario.request("case_study", home) for s in _stories("whole_bin", True))
    assert new_bin == {"bin_type": "case_study", "bin_xyz_yaw": home, "dirty": False, "park_offset_xy_yaw": (0, 0, 0)}
    assert adjusted == {"park_offset_xy_yaw": (0.008, -0.006, math.radians(0.5))}
    assert wash == {"dirty": True, "powder_amount": 0.01, "seed": 21}
    assert beyond == {"park_offset_xy_yaw": (-0.15, 0.0, math.radians(5.0)), "dirty": False}
    assert _stories("single_station", True)[1].scenario.request("case_study", home) == {}  # nothing sent


def test_the_single_station_story_adds_its_wash_cycle() -> None:
    plain, washed = _stories("single_station", wash=False), _stories("single_station", wash=True)
    assert [s.start.get("mode") for s in washed].count("wash_and_verify") == 1
    assert len(washed) == len(plain) + 1
    assert washed[-1].expect == plain[-1].expect
    # one surface from one park: no clean certificate (classifier.verdict.min_seen_fraction)
    assert {s.expect.verdict for s in plain if s.expect.outcome == "completed"} == {"incomplete", "dirty"}


def test_the_whole_bin_wash_cycle_must_end_clean_after_a_wash_round() -> None:
    """Its powder lies where a nozzle reaches: the story fails unless the rounds leave the bin clean
    (the single-station one washes from one park, and dirt it cannot reach keeps that bin dirty)."""
    (whole,) = [s for s in _stories("whole_bin", True) if s.start.get("mode")]
    assert whole.expect.verdict == "clean" and whole.expect.washed
    (single,) = [s for s in _stories("single_station", True) if s.start.get("mode")]
    assert single.expect.verdict is None
    # the wash story on its own: the new bin's plan, then the same wash cycle
    only = _stories("wash_only", True)
    assert [s.story for s in only] == [_stories("whole_bin", True)[0].story, whole.story]
    assert only[1].model_copy(update={"wash": True}) == whole


def test_story_n_plays_story_1_then_n_with_their_numbers_and_refuses_one_it_lacks() -> None:
    ap = _parser()
    assert ap.parse_args(["demo"]).story is None
    stories = _stories("whole_bin", wash=True)
    assert [n for n, _ in chosen(stories, None)] == [1, 2, 3, 4]
    (n1, s1), (n3, s3) = chosen(stories, ap.parse_args(["demo", "--story", "3"]).story)
    assert (n1, n3) == (1, 3) and s1 is stories[0] and s3.start.get("mode") == "wash_and_verify"
    with pytest.raises(ConfigError, match="--story 5: this demo has stories 1-4"):
        chosen(stories, [5])


def test_the_new_bin_story_commissions_before_the_clean_and_dirty_cycles() -> None:
    """Issue 34: after story 1's plan a commissioning cycle (no story number of its own: --story N keeps its
    meaning); each cycle prints what its surfaces were judged against."""
    from types import SimpleNamespace

    for name in ("whole_bin", "single_station"):
        stories = _stories(name, wash=True)
        assert ["commission" in s.steps for s in stories] == [True] + [False] * (len(stories) - 1)
        assert stories[0].steps.index("wait_plan") < stories[0].steps.index("commission")
    view = SimpleNamespace(label="clean", decided_by="reference")
    res = SimpleNamespace(decision_path={"external": "references"}, viewpoints=[view, view])
    assert paths(res) == "   decision path: external references (views: 2 by reference)"
    assert "none" in paths(SimpleNamespace(decision_path=None, viewpoints=[]))


def test_a_malformed_story_file_is_refused_naming_the_key_and_the_file(tmp_path: Path) -> None:
    good = (STORIES_DIR / "wash_only.yaml").read_text(encoding="utf-8")
    bad = tmp_path / "typo.yaml"
    bad.write_text(good.replace("expect: {outcome: completed", "expekt: {outcome: completed"), encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        load_story_file(story_path(str(bad)))
    assert "unknown key 'stories.1.expekt'" in str(err.value) and str(bad) in str(err.value)
    bad.write_text(good.replace("seed: 21", "sed: 21"), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"unknown key 'stories.1.scenario.sed'; allowed keys here: \[.*'seed'"):
        load_story_file(bad)
    bad.write_text(good.replace("[scenario, cycle, check", "[scenario, cycle, chek"), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"key 'stories.0.steps.2'.*'chek'"):
        load_story_file(bad)
    bad.write_text(good.replace("[scenario, cycle, check", "[scenario, check, cycle"), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"stories.0.*\['check'\] read the cycle's result, so they come after"):
        load_story_file(bad)
    with pytest.raises(ConfigError, match="--stories 'nope': neither a story file nor one of the shipped stories"):
        story_path("nope")
