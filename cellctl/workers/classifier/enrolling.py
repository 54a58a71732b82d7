"""The classifier worker's ``enroll`` op: a commissioning cycle's views teach a surface's detector.

Request :class:`~cellctl.messages.EnrollRequest` (surface, a folder of the surface's clean views,
the file to write), reply :class:`~cellctl.messages.EnrollReply`. The shipped detector of the
surface is the base every time (never a previously enrolled file: commissioning twice must not
drift), :func:`cellctl.classify.enroll.enroll_detector` adapts it, the file is written and loaded
like a ``classifier.detector_files`` entry, and from then on it decides the surface's views
(until the worker restarts: then ``classifier.detector_files`` says what loads; the commissioning
record names the file to point it at). A refusal (too few views, views that score like dirt)
is a :class:`~cellctl.errors.ClassifierError` reply; the detector in use stays.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from cellctl.errors import ClassifierError
from cellctl.hashing import file_sha256
from cellctl.messages import EnrollReply, EnrollRequest

__all__ = ["enroll_surface"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


def enroll_surface(
    service: Any, req: EnrollRequest, models_dir: Path, runtime: str, threads: int | None
) -> EnrollReply:
    """Enroll ``req.surface`` from ``req.images`` into ``req.out`` and make ``service`` decide with it.

    Args:
        service: the worker's :class:`~cellctl.workers.classifier.ClassifierService`.
        models_dir: ``classifier.models_dir`` (the shipped ``<surface>.detect.pt`` and its export).

    Raises:
        ClassifierError: no shipped detector, a bad folder, too few views, or views that score like dirt.
    """
    from cellctl.classify.enroll import enroll_detector, folder_images, save_enrolled
    from cellctl.classify.fusion import Detector, detector_path
    from cellctl.classify.runtime import onnx_path

    s = req.surface
    if service.decision == "supervised":
        raise ClassifierError(f"classifier.decision is 'supervised': no detector of {s!r} to enroll")
    images = folder_images(req.images)
    base = detector_path(models_dir, s)
    log.info("enrolling %s from %d views under %s", s, len(images), req.images)
    det = enroll_detector(
        Detector.load(base, surface=s), images, s, source=Path(req.images), progress=lambda m: log.info("%s", m)
    )
    out = Path(req.out)
    save_enrolled(det, out)
    also = (onnx_path(base),)  # enrollment changes no network weights: the shipped export serves it
    loaded = Detector.load(out, surface=s, runtime=runtime, threads=threads, also_onnx=also)
    with service._lock:  # a batch in flight finishes on the detector it started with
        service.detectors[s] = loaded
        service.paths[s] = out
    log.info("enrolled %s: %s (%s) now decides", s, loaded.model_id, out)
    return EnrollReply(
        surface=s,
        model_id=loaded.model_id,
        path=str(out),
        sha256=file_sha256(out),
        threshold=loaded.threshold,
        images=len(images),
    )
