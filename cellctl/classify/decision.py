"""The decision rule of a clean/dirty model, shared by inference and evaluation.

Label 1 = dirty is the positive class. A model calls an image dirty when
``p_dirty >= threshold``; it flags the image *uncertain* (for a human check) when
``|logit(p_dirty) − logit(threshold)| < band``. A leaf module: :mod:`cellctl.classify.infer`
applies the rule and :mod:`cellctl.classify.evaluate` measures it, neither imports the other
for it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["UNCERTAIN_LOGIT_BAND", "is_uncertain", "logit"]

UNCERTAIN_LOGIT_BAND = 1.5
"""Images within this many logits of the threshold are flagged ``uncertain`` (p 0.18–0.82 at 0.5)."""

_EPS = 1e-6


def logit(p: ArrayLike | float) -> np.ndarray:
    """``log(p / (1 − p))`` with ``p`` clipped to ``[1e-6, 1 − 1e-6]`` (finite at 0 and 1)."""
    q = np.clip(np.asarray(p, np.float64), _EPS, 1 - _EPS)
    return np.log(q / (1 - q))


def is_uncertain(p_dirty: ArrayLike, threshold: float, band: float) -> np.ndarray:
    """True where ``p_dirty`` lies within ``band`` logits of the threshold."""
    return np.abs(logit(np.asarray(p_dirty)) - logit(threshold)) < band
