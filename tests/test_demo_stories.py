"""`cellctl demo`'s stories: the whole-bin dirty bin is a wash-and-verify cycle unless `--no-wash`."""

from __future__ import annotations

import math

from cellctl.cli.demo import _stories, register

HOME = (0.0, 0.0, 0.0, 0.0)
NUDGED = (0.008, -0.006, math.radians(0.5))
MOVED = (-0.15, 0.0, math.radians(5.0))


def test_the_default_demo_washes_and_no_wash_skips_it() -> None:
    import argparse

    ap = argparse.ArgumentParser()
    register(ap.add_subparsers())
    assert ap.parse_args(["demo"]).wash is True
    assert ap.parse_args(["demo", "--no-wash"]).wash is False


def test_the_whole_bin_story_tells_dirty_and_washed_clean_in_one_cycle() -> None:
    plain = _stories("case_study", HOME, NUDGED, MOVED, whole=True, wash=False)
    washed = _stories("case_study", HOME, NUDGED, MOVED, whole=True, wash=True)
    assert all(s.params.get("mode") != "wash_and_verify" for s in plain)
    assert [s.params.get("mode") for s in washed].count("wash_and_verify") == 1
    # the wash cycle takes the plain dirty scan's place (its scan is the dirty verdict): no extra scan
    assert len(washed) == len(plain)
    (dirty,) = [s for s in plain if s.expect.verdict == "dirty"]
    (wash,) = [s for s in washed if s.params.get("mode")]
    assert washed.index(wash) == plain.index(dirty) and wash.scenario["dirty"] is True
    assert washed[-1].expect == plain[-1].expect


def test_the_single_station_story_adds_its_wash_cycle() -> None:
    plain = _stories("case_study", HOME, NUDGED, MOVED, whole=False, wash=False)
    washed = _stories("case_study", HOME, NUDGED, MOVED, whole=False, wash=True)
    assert [s.params.get("mode") for s in washed].count("wash_and_verify") == 1
    assert len(washed) == len(plain) + 1
    assert washed[-1].expect == plain[-1].expect
    # one surface from one park: no clean certificate (classifier.verdict.min_seen_fraction)
    assert {s.expect.verdict for s in plain if s.expect.outcome == "completed"} == {"incomplete", "dirty"}


def test_the_whole_bin_wash_cycle_must_end_clean_after_a_wash_round() -> None:
    """Its powder lies where a nozzle reaches: the story fails unless the rounds leave the bin clean
    (the single-station one washes from one park, and dirt it cannot reach keeps that bin dirty)."""
    (whole,) = [s for s in _stories("case_study", HOME, NUDGED, MOVED, True, True) if s.params.get("mode")]
    assert whole.expect.verdict == "clean" and whole.expect.washed
    (single,) = [s for s in _stories("case_study", HOME, NUDGED, MOVED, False, True) if s.params.get("mode")]
    assert single.expect.verdict is None


def test_story_n_plays_story_1_then_n_with_their_numbers_and_refuses_one_it_lacks() -> None:
    import argparse

    import pytest

    from cellctl.cli.demo import _chosen
    from cellctl.errors import ConfigError

    ap = argparse.ArgumentParser()
    register(ap.add_subparsers())
    assert ap.parse_args(["demo"]).story is None
    stories = _stories("case_study", HOME, NUDGED, MOVED, whole=True, wash=True)
    assert [n for n, _ in _chosen(stories, None)] == [1, 2, 3, 4]
    (n1, s1), (n3, s3) = _chosen(stories, ap.parse_args(["demo", "--story", "3"]).story)
    assert (n1, n3) == (1, 3) and s1 is stories[0] and s3.params.get("mode") == "wash_and_verify"
    with pytest.raises(ConfigError, match="--story 5: this demo has stories 1-4"):
        _chosen(stories, [5])


def test_the_new_bin_story_commissions_before_the_clean_and_dirty_cycles() -> None:
    """Issue 34: after story 1's plan a commissioning cycle (no story number of its own: --story N keeps its
    meaning); each cycle prints what its surfaces were judged against."""
    from types import SimpleNamespace

    from cellctl.cli.demo import _paths

    for whole in (True, False):
        stories = _stories("case_study", HOME, NUDGED, MOVED, whole=whole, wash=True)
        assert [s.commission for s in stories] == [True] + [False] * (len(stories) - 1)
    view = SimpleNamespace(label="clean", decided_by="reference")
    res = SimpleNamespace(decision_path={"external": "references"}, viewpoints=[view, view])
    assert _paths(res) == "   decision path: external references (views: 2 by reference)"
    assert "none" in _paths(SimpleNamespace(decision_path=None, viewpoints=[]))
