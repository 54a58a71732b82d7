"""`cellctl demo`'s stories: the wash-and-verify cycle is in them only with `--wash`."""

from __future__ import annotations

import math

import pytest

from cellctl.cli.demo import _stories

HOME = (0.0, 0.0, 0.0, 0.0)
NUDGED = (0.008, -0.006, math.radians(0.5))
MOVED = (-0.15, 0.0, math.radians(5.0))


@pytest.mark.parametrize("whole", [True, False])
def test_the_wash_cycle_is_played_only_when_asked_for(whole: bool) -> None:
    plain = _stories("case_study", HOME, NUDGED, MOVED, whole=whole, wash=False)
    washed = _stories("case_study", HOME, NUDGED, MOVED, whole=whole, wash=True)
    assert all(s.params.get("mode") != "wash_and_verify" for s in plain)
    modes = [s.params.get("mode") for s in washed]
    assert modes.count("wash_and_verify") == 1
    assert len(washed) == len(plain) + 1
    # the story still ends on the cycle beyond tolerance
    assert washed[-1].expect == plain[-1].expect


def test_the_whole_bin_wash_cycle_must_end_clean_after_a_wash_round() -> None:
    """Its powder lies where a nozzle reaches: the story fails unless the rounds leave the bin clean
    (the single-station one washes from one park, and dirt it cannot reach keeps that bin dirty)."""
    (whole,) = [s for s in _stories("case_study", HOME, NUDGED, MOVED, True, True) if s.params.get("mode")]
    assert whole.expect.verdict == "clean" and whole.expect.washed
    (single,) = [s for s in _stories("case_study", HOME, NUDGED, MOVED, False, True) if s.params.get("mode")]
    assert single.expect.verdict is None
