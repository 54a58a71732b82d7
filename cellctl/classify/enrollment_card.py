"""The card inside a site-enrolled detector file: its format and the check made at load.

A leaf of :mod:`cellctl.classify.enroll` (which writes the card) that
:meth:`~cellctl.classify.fusion.Detector.load` imports to check it, so loading a detector does not
import the enrollment procedure (and the two modules do not import each other).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from cellctl.errors import ClassifierError

__all__ = ["ENROLLMENT_FORMAT", "check_enrollment"]

ENROLLMENT_FORMAT = "cellctl-enrollment/1"
"""Format of the enrollment card a site-enrolled detector file carries."""


def check_enrollment(blob: dict[str, Any], path: Path) -> dict[str, Any]:
    """The enrollment card of a loaded blob, checked (called by ``Detector.load``).

    Raises:
        ClassifierError: the card is not ours, or disagrees with the blob.
    """
    card = blob.get("enrollment")
    if not isinstance(card, dict) or card.get("format") != ENROLLMENT_FORMAT:
        got = card.get("format") if isinstance(card, dict) else type(card).__name__
        raise ClassifierError(f"{str(path)!r}: enrollment card format {got!r}, expected {ENROLLMENT_FORMAT!r}")
    if card.get("surface") != blob.get("surface"):
        raise ClassifierError(
            f"{str(path)!r}: enrollment card is for {card.get('surface')!r}, weights for {blob.get('surface')!r}"
        )
    if card.get("threshold") != blob.get("threshold"):
        raise ClassifierError(
            f"{str(path)!r}: enrollment card threshold {card.get('threshold')!r} is not the file's "
            f"{blob.get('threshold')!r}"
        )
    return card
