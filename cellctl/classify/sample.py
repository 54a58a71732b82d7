"""A drawn training image (:class:`Sample`) and the rule that labels it from its powder mask.

The vocabulary shared by the dataset generator (:mod:`cellctl.classify.synth`) and its image
sources (procedural textures, :mod:`cellctl.classify._twin_source`): a leaf module, so that
neither source imports the generator back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["MIN_CONTRAST", "MIN_VISIBLE_FRACTION", "POWDER_ALPHA", "Sample", "label_from_mask"]

MIN_VISIBLE_FRACTION = 0.003
"""Smallest fraction of the frame showing powder for a *dirty* label (0.3 %: ~50 px at 128²)."""
POWDER_ALPHA = 0.5
"""Powder opacity at which a pixel counts as showing powder."""
MIN_CONTRAST = 12
"""Grey levels (8-bit, any channel) by which powder must change a pixel to count as visible."""


@dataclass(frozen=True)
class Sample:
    """One rendered image: RGB uint8 ``(H, W, 3)``, powder opacity ``(H, W)`` in [0, 1], params."""

    rgb: NDArray[np.uint8]
    powder: NDArray[np.float32]
    params: dict[str, Any]
    surface: NDArray[np.bool_] | None = None
    """Pixels showing the inspected surface (twin renders), None = all (close-up textures)."""


def label_from_mask(
    powder: NDArray[np.floating], min_fraction: float = MIN_VISIBLE_FRACTION, present: float | None = None
) -> str | None:
    """``"dirty"``, ``"clean"`` or ``None`` (ambiguous: discard) from a visible-powder map.

    Args:
        powder: per-pixel visible powder opacity (or 0/1 visibility) of the image.
        min_fraction: smallest visible fraction for *dirty*.
        present: fraction of pixels where powder lies in view at all, visible or not (e.g.
            washed out by glare). An image with powder present but not visible enough is
            ambiguous, never *clean*.
    """
    frac = float((np.asarray(powder) >= POWDER_ALPHA).mean())
    if frac >= min_fraction:
        return "dirty"
    if frac == 0.0 and not present:
        return "clean"
    return None
