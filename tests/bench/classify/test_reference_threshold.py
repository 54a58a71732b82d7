"""The reference fusion's threshold from held-out clean pairs (cellctl.bench.classify.reference.clean_threshold)."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.bench.classify.reference import ScoredPair, clean_threshold
from cellctl.classify.reference import ReferenceFusion


def _pair(label: int, p: float) -> ScoredPair:
    """A scored pair whose image probability under :func:`_fusion` is ``p`` (one patch carries the logit)."""
    feats = np.full((3, 2, 2), -20.0, np.float32)
    feats[0, 0, 0] = np.log(p / (1 - p))
    z = np.zeros((2, 2), np.float32)
    return ScoredPair(label, "none" if not label else "stain", z, z, p, None, feats, z)  # type: ignore[arg-type]


def _fusion(threshold: float) -> ReferenceFusion:
    # change logit = colour feature; patch logit = change logit; p = sigmoid(max patch logit)
    return ReferenceFusion("external", (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0, 0.0, 0.0), (1.0, 0.0), threshold, 1.5)


def test_the_threshold_rises_above_every_held_out_clean_pair_half_way_to_the_next_dirty() -> None:
    fit = [_pair(1, 0.45), _pair(1, 0.9)]
    out = clean_threshold(_fusion(0.2), fit, [_pair(0, 0.1), _pair(0, 0.35)], seed=7)
    mid = 1 / (1 + np.exp(-(np.log(0.35 / 0.65) + np.log(0.45 / 0.55)) / 2))
    assert out.threshold == pytest.approx(mid)
    assert out.card["threshold_clean_pairs"]["false_dirty"]["k"] == 0
    assert out.card["threshold_fit"] == 0.2 and out.card["threshold_fit_false_clean"]["k"] == 0


def test_the_threshold_never_falls_below_the_fit_nor_rises_past_even_odds() -> None:
    fit = [_pair(1, 0.95)]
    assert clean_threshold(_fusion(0.3), fit, [_pair(0, 0.1)], seed=7).threshold == 0.3
    high = clean_threshold(_fusion(0.3), fit, [_pair(0, 0.8)], seed=7)
    assert high.threshold == 0.5 and high.card["threshold_clean_pairs"]["false_dirty"]["k"] == 1
