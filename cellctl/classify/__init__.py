"""Clean/dirty classifier: models, data, training, evaluation, inference, data collection.

This ``__init__`` is light (no torch) so that the supervisor may import
:mod:`cellctl.classify.collect`; the torch modules are imported explicitly:
:mod:`~cellctl.classify.nets`, :mod:`~cellctl.classify.data`, :mod:`~cellctl.classify.train`,
:mod:`~cellctl.classify.evaluate`, :mod:`~cellctl.classify.infer`, :mod:`~cellctl.classify.synth`;
the combined detector: :mod:`~cellctl.classify.contamination` (families),
:mod:`~cellctl.classify.shifted` (held-out generator), :mod:`~cellctl.classify.contam_dataset`,
:mod:`~cellctl.classify.anomaly` (clean-only bank), :mod:`~cellctl.classify.fusion` (the
decision), :mod:`~cellctl.classify.heatmap` (light: heat maps onto mesh faces, re-look poses).
"""

from cellctl.classify.collect import (
    LABELS,
    SURFACES,
    capture_path,
    check_label,
    check_surface,
    store_capture,
    store_image,
)

__all__ = [
    "LABELS",
    "SURFACES",
    "capture_path",
    "check_label",
    "check_surface",
    "store_capture",
    "store_image",
]
