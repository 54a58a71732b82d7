"""Metrics and threshold choice."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.classify.decision import is_uncertain
from cellctl.classify.evaluate import choose_threshold, metrics, roc_auc, roc_curve
from cellctl.errors import ClassifierError


def test_roc_auc_known_values() -> None:
    assert roc_auc([0.1, 0.2, 0.8, 0.9], [0, 0, 1, 1]) == 1.0
    assert roc_auc([0.9, 0.8, 0.2, 0.1], [0, 0, 1, 1]) == 0.0
    assert roc_auc([0.5, 0.5], [0, 1]) == 0.5
    assert roc_auc([0.3, 0.4], [1, 1]) is None
    fpr, tpr, _ = roc_curve([0.1, 0.4, 0.35, 0.8], [0, 0, 1, 1])
    assert fpr[-1] == 1.0 and tpr[-1] == 1.0


def test_threshold_meets_target_false_clean_rate() -> None:
    rng = np.random.default_rng(0)
    y = np.r_[np.zeros(500), np.ones(500)].astype(int)
    p = np.clip(np.r_[rng.beta(2, 8, 500), rng.beta(8, 2, 500)], 0, 1)
    for target in (0.0, 0.01, 0.05):
        t = choose_threshold(p, y, target)
        fc = ((p < t) & (y == 1)).sum() / 500
        assert fc <= target + 1e-12
        assert t <= 0.5
    with pytest.raises(ClassifierError, match="without dirty"):
        choose_threshold([0.1, 0.2], [0, 0], 0.01)
    with pytest.raises(ClassifierError, match="must be in"):
        choose_threshold(p, y, 1.5)


def test_metrics_confusion_and_uncertain_band() -> None:
    p = np.array([0.05, 0.6, 0.4, 0.95])
    y = np.array([0, 0, 1, 1])
    m = metrics(p, y, 0.5, 1.0)
    assert m["confusion"] == {
        "clean_as_clean": 1,
        "clean_as_dirty": 1,
        "dirty_as_clean": 1,
        "dirty_as_dirty": 1,
    }
    assert m["false_clean_rate"] == 0.5 and m["accuracy"] == 0.5
    assert list(is_uncertain(p, 0.5, 1.0)) == [False, True, True, False]
    assert m["uncertain_fraction"] == 0.5 and m["accuracy_certain"] == 1.0


def test_temperature_fit_recovers_the_scale() -> None:
    """Margins sharpened ×4 are scaled back to about T = 4 (calibration keeps the ranking)."""
    from cellctl.classify.calibration import fit_temperature

    rng = np.random.default_rng(0)
    z_true = rng.normal(0, 2, 4000)
    y = (rng.random(4000) < 1 / (1 + np.exp(-z_true))).astype(int)
    t = fit_temperature(4 * z_true, y)
    assert 3.4 < t < 4.7
    assert fit_temperature(np.array([-5.0, 5.0]), np.array([0, 1])) == 1.0  # separable: never sharpens


def test_threshold_sits_midway_in_logit_space() -> None:
    """Separable scores: threshold between the top clean and the lowest dirty score."""
    p = np.array([0.001, 0.01, 0.2, 0.3, 0.9])
    y = np.array([0, 0, 1, 1, 1])
    t = choose_threshold(p, y, 0.0)
    assert 0.01 < t < 0.2
    assert abs(np.log(t / (1 - t)) - (np.log(0.01 / 0.99) + np.log(0.2 / 0.8)) / 2) < 1e-9
