"""The classifier worker's reference comparison: a view judged against its commissioned reference.

A :class:`~cellctl.messages.ClassifyRequest` with ``reference`` (the scan sends one for every view
of a plan a reference set holds) is decided by :func:`cellctl.classify.reference.decide`: the
stored clean view aligned to the new one (pose-delta homography, refined by ECC), its change map
fused with the detector's evidence in the calibrated decision ``<surface>.reference.json``. The
fusion was fitted on the *shipped* detector's maps (its card names the model id), so that detector
computes them, also after a site enrollment replaced the detector that decides views without a
reference. A view whose reference cannot be used — no fitted fusion, an unreadable or altered
image, a pose past the mirror tolerance, a rejected alignment — is decided by the detector in use
alone; the reply says which path decided and why (``decided_by``, ``reference_reason``).

Reference images are read from the set's folder (the reference root is shared with the
supervisor's host, as for enrollment), checked against the manifest's sha256 and kept decoded in a
small cache: a cycle revisits the same ~100 views.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

from cellctl.errors import CellError, ClassifierError
from cellctl.hashing import bytes_sha256
from cellctl.images import decode_image
from cellctl.messages import ClassifyReference, ClassifyReply

__all__ = ["CACHED_REFERENCES", "ReferenceJudge"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

CACHED_REFERENCES = 256
"""Decoded reference images kept (a whole-bin plan has ~100 views; 1280×720 RGB is 2.7 MB each)."""


class ReferenceJudge:
    """The fitted fusions of the surfaces and the detectors they were fitted on.

    Args:
        models_dir: ``classifier.models_dir`` (``<surface>.reference.json`` beside the detectors).
        detectors: the shipped detectors, by surface (before any enrolled file replaces one).
        max_pixels: pixel budget of a reference image.
    """

    def __init__(self, models_dir: Path, detectors: dict[str, Any], max_pixels: int) -> None:
        import cv2

        from cellctl.classify.reference import ReferenceFusion, fusion_path

        # at the 128 px work size OpenCV's thread hand-offs cost more than they save on a shared
        # 2-core host (ECC 17 -> 11 ms at load 30: cellctl.bench.classify.reference.latency)
        cv2.setNumThreads(1)
        self.detectors: dict[str, Any] = {}
        self.fusions: dict[str, ReferenceFusion] = {}
        self.problems: dict[str, str] = {}
        self.max_pixels = max_pixels
        self._images: OrderedDict[str, np.ndarray] = OrderedDict()
        for s, det in detectors.items():
            path = fusion_path(models_dir, s)
            if not path.exists():
                self.problems[s] = f"no reference fusion {str(path)!r}"
                continue
            try:
                fusion = ReferenceFusion.load(path, s)
            except ClassifierError as err:
                self.problems[s] = str(err)
                continue
            fitted_on = fusion.card.get("model_id")
            if fitted_on is not None and fitted_on != det.model_id:
                # weights fitted on another detector's logits and distances mean nothing for this one
                self.problems[s] = f"{path.name} was fitted on {fitted_on!r}, the shipped detector is {det.model_id!r}"
                continue
            self.fusions[s], self.detectors[s] = fusion, det
        for s, why in self.problems.items():
            log.warning("classifier: views of %s are never compared with references: %s", s, why)

    def _reference_rgb(self, ref: ClassifyReference) -> np.ndarray:
        hit = self._images.get(ref.sha256)
        if hit is not None:
            self._images.move_to_end(ref.sha256)
            return hit
        try:
            data = Path(ref.image).read_bytes()
        except OSError as err:
            raise ClassifierError(f"reference image {ref.image!r} cannot be read: {err.strerror}") from err
        if bytes_sha256(data) != ref.sha256:
            raise ClassifierError(f"reference image {ref.image!r} is not the one its set's manifest records")
        rgb = decode_image(data, ref.image, error=ClassifierError, max_pixels=self.max_pixels)
        self._images[ref.sha256] = rgb
        while len(self._images) > CACHED_REFERENCES:
            self._images.popitem(last=False)
        return rgb

    def judge(self, surface: str, img: np.ndarray, ref: ClassifyReference) -> ClassifyReply | str:
        """The view's reply decided with its reference, or the reason the detector in use must decide alone."""
        from cellctl.classify.heatmap import encode_heat
        from cellctl.classify.reference import Plane, ReferenceView, decide

        fusion = self.fusions.get(surface)
        if fusion is None:
            return "no_fusion"
        try:
            rgb = self._reference_rgb(ref)
        except CellError as err:
            log.warning("view of %s decided without its reference: %s", surface, err)
            return "unreadable"
        view = ReferenceView(
            rgb, ref.reference_pose.matrix(), Plane(ref.plane_normal, ref.plane_distance), ref.intrinsics.K()
        )
        det = self.detectors[surface]
        d = decide(det, fusion, img, ref.view_pose.matrix(), view)
        if d.path != "reference":
            return d.reason
        return ClassifyReply(
            label=d.label,  # type: ignore[arg-type]
            p_dirty=d.p_dirty,
            uncertain=d.uncertain,
            model_id=det.model_id,
            heatmap=encode_heat(d.heat),
            heat_grid=int(d.heat.shape[0]),
            decided_by="reference",
            reference_reason="aligned",
        )
