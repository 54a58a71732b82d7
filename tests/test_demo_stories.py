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
