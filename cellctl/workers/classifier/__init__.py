"""Classifier worker: serves ``cell/<id>/classifier/classify`` (image + surface → label).

Request: :class:`~cellctl.messages.ClassifyRequest` as the query attachment, the encoded
PNG/JPEG image as the payload. Reply: :class:`~cellctl.messages.ClassifyReply` (label,
``p_dirty``, ``uncertain``, ``model_id``; from the combined detector also ``p_supervised``,
``anomaly_z`` and the per-patch heat map). Both surface models are loaded once at start; a
surface with a detector (``<surface>.detect.pt``, :mod:`cellctl.classify.fusion`) is decided by
it unless ``classifier.decision`` is ``supervised``; ``classifier.detector_files`` replaces a
surface's shipped detector by a site-enrolled file (:mod:`cellctl.classify.enroll`). The
``models`` op (``cell/<id>/classifier/models``, :class:`~cellctl.messages.ClassifierModels`) and
the start-up log line name what decides each surface. A request that carries the view's commissioned
reference (``ClassifyRequest.reference``) is decided against it when the surface has a fitted fusion and
the reference aligns (:mod:`cellctl.workers.classifier.referencing`); the reply says which path decided
(``decided_by``) and, when the detector decided alone, why (``reference_reason``).
Queries that are already queued when the worker picks one up are answered as one batch (up
to ``classifier.max_batch``), one forward pass per surface. A bad image, an unknown surface or
a surface whose weights are missing gets a :class:`~cellctl.errors.ClassifierError` error
reply for that query only; the worker keeps serving.

Backends: ``torch`` (the only one; torch is imported here, never by the supervisor).
"""

from __future__ import annotations

import logging
import queue
import threading
from pathlib import Path
from typing import Any

import zenoh

from cellctl.bus import keys
from cellctl.bus.codec import MAX_PAYLOAD_BYTES, decode_as, encode
from cellctl.config import CellConfig
from cellctl.errors import CellError, ClassifierError, ConfigError, ProtocolError
from cellctl.images import MAX_IMAGE_BYTES, MAX_IMAGE_PIXELS, decode_image
from cellctl.messages import (
    ClassifierModel,
    ClassifierModels,
    ClassifierModelsRequest,
    ClassifyReply,
    ClassifyRequest,
    EnrollRequest,
    ErrorReply,
)
from cellctl.surface import SURFACES, check_surface
from cellctl.workers.classifier.referencing import ReferenceJudge

__all__ = ["BACKENDS", "BatchingClassifyServer", "ClassifierService", "run_worker"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

BACKENDS = ("torch",)


class ClassifierService:
    """Both surface models, loaded once; classifies batches of decoded requests.

    Args:
        models_dir: folder holding ``external.pt`` and ``internal.pt``.
        variant: ``fp32`` or ``fused``.
        threads: torch CPU threads (None: all cores).
        max_pixels: pixel budget of a request's image, checked from its header before decoding.
        runtime: ``classifier.runtime``: what runs the detectors' networks (:mod:`cellctl.classify.runtime`).
    """

    def __init__(
        self,
        models_dir: Path,
        variant: str = "fused",
        threads: int | None = None,
        decision: str = "auto",
        max_pixels: int = MAX_IMAGE_PIXELS,
        runtime: str = "auto",
        detector_files: dict[str, Path] | None = None,
    ) -> None:
        import os

        import torch

        from cellctl.classify.fusion import Detector, detector_path, load_detectors
        from cellctl.classify.infer import load_surface_models
        from cellctl.classify.runtime import onnx_path

        torch.set_num_threads(threads or os.cpu_count() or 1)
        self.decision = decision
        self.references: ReferenceJudge | None = None
        self.detectors: dict[str, Any] = {}
        self.paths: dict[str, Path] = {}
        if decision in ("auto", "detector"):
            self.detectors, missing = load_detectors(models_dir, runtime, threads)
            self.paths = {s: detector_path(models_dir, s) for s in self.detectors}
            # the reference fusions were fitted on the shipped detectors' maps: those compute them
            self.references = ReferenceJudge(models_dir, dict(self.detectors), max_pixels)
            for s, path in (detector_files or {}).items():
                # a configured enrolled file must load: never fall back to the shipped one silently;
                # it shares the shipped detector's network export (enrollment changes no weights)
                also = (onnx_path(detector_path(models_dir, s)),)
                self.detectors[s] = Detector.load(path, surface=s, runtime=runtime, threads=threads, also_onnx=also)
                self.paths[s] = Path(path)
                missing.pop(s, None)
            if decision == "detector" and missing:
                raise ClassifierError(f"classifier.decision is 'detector' but: {missing}")
        self.models, self.problems = load_surface_models(models_dir, variant)
        self.paths.update({s: Path(models_dir) / f"{s}.pt" for s in self.models if s not in self.detectors})
        for s in self.detectors:
            self.problems.pop(s, None)
        for s, why in self.problems.items():
            log.warning("classifier: no model for surface %s: %s", s, why)
        self._lock = threading.Lock()
        self.max_pixels = max_pixels

    def describe(self) -> ClassifierModels:
        """What decides each surface (shipped detector, enrolled file, whole-image model), for the
        worker's ``models`` op and its start-up log line."""
        out: dict[str, ClassifierModel] = {}
        for s, det in self.detectors.items():
            card = det.enrollment
            on = {"source": card.get("source"), "base": card.get("base", {}).get("model_id")} if card else None
            kind = "enrolled" if card else "detector"
            run = det.engine.describe() if det.engine is not None else {"runtime": "torch"}
            out[s] = ClassifierModel(
                model_id=det.model_id,
                kind=kind,
                path=str(self.paths[s]),
                threshold=det.threshold,
                enrolled_on=on,
                runtime=run,
            )
        for s, m in self.models.items():
            if s not in out:
                out[s] = ClassifierModel(
                    model_id=m.model_id, kind="supervised", path=str(self.paths[s]), threshold=m.threshold
                )
        return ClassifierModels(decision=self.decision, models=out, problems=dict(self.problems))  # type: ignore[arg-type]

    def classify(self, items: list[tuple[ClassifyRequest, bytes]]) -> list[ClassifyReply | CellError]:
        """Classify a batch; each item gets a reply or the error that refuses it."""
        out: list[ClassifyReply | CellError | None] = [None] * len(items)
        groups: dict[str, list[tuple[int, Any]]] = {}
        for i, (req, data) in enumerate(items):
            try:
                check_surface(req.surface, ClassifierError)
                if req.surface not in self.models and req.surface not in self.detectors:
                    raise ClassifierError(f"no model for surface {req.surface!r}: {self.problems.get(req.surface)}")
                if len(data) > MAX_IMAGE_BYTES:
                    raise ClassifierError(f"image of {len(data)} bytes exceeds the limit of {MAX_IMAGE_BYTES} bytes")
                img = decode_image(
                    data, f"({req.format}, {len(data)} bytes)", error=ClassifierError, max_pixels=self.max_pixels
                )
                groups.setdefault(req.surface, []).append((i, img))
            except CellError as err:
                out[i] = err
        reasons: dict[int, str] = {}  # item -> why its reference did not decide it
        with self._lock:
            for surface, entries in groups.items():
                if surface in self.detectors:
                    from cellctl.classify.heatmap import encode_heat

                    alone = []
                    for i, im in entries:
                        ref = items[i][0].reference
                        if ref is None:
                            alone.append((i, im))
                            continue
                        judged = self.references.judge(surface, im, ref) if self.references else "no_fusion"
                        if isinstance(judged, str):
                            reasons[i] = judged
                            alone.append((i, im))
                        else:
                            out[i] = judged
                    if not alone:
                        continue
                    for (i, _), d in zip(alone, self.detectors[surface].predict([im for _, im in alone]), strict=True):
                        out[i] = ClassifyReply(
                            label=d.label,
                            p_dirty=d.p_dirty,
                            uncertain=d.uncertain,
                            model_id=d.model_id,
                            p_supervised=d.p_supervised,
                            anomaly_z=d.anomaly_z,
                            heatmap=encode_heat(d.heat),
                            heat_grid=int(d.heat.shape[0]),
                            decided_by="detector",
                            reference_reason=reasons.get(i),  # type: ignore[arg-type]
                        )
                    continue
                preds = self.models[surface].predict([img for _, img in entries])
                for (i, _), pr in zip(entries, preds, strict=True):
                    ref = items[i][0].reference
                    out[i] = ClassifyReply(
                        label=pr.label,
                        p_dirty=pr.p_dirty,
                        uncertain=pr.uncertain,
                        model_id=pr.model_id,
                        decided_by="model",
                        reference_reason="no_fusion" if ref is not None else None,
                    )
        return [o if o is not None else ClassifierError("internal: item left unanswered") for o in out]


class BatchingClassifyServer:
    """The classify queryable: drains every queued query into one batch.

    Zenoh callbacks only enqueue; one thread answers.
    """

    def __init__(self, session: zenoh.Session, cell_id: str, service: ClassifierService, max_batch: int = 16) -> None:
        self.service = service
        self.max_batch = max_batch
        self.key = keys.classifier_classify(cell_id)
        self.batches: list[int] = []  # sizes of the batches run (for tests and stats)
        self._closed = threading.Event()
        # The Zenoh callback only enqueues; a Python queue (not a Zenoh channel) so that
        # close() never races a thread blocked inside the channel's recv().
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=1024)
        self._queryable = session.declare_queryable(self.key, self._enqueue, complete=True)
        self._thread = threading.Thread(target=self._drain, name="classifier-classify", daemon=True)
        self._thread.start()

    def _enqueue(self, q: Any) -> None:
        try:
            self._queue.put_nowait(q)
        except queue.Full:
            q.reply_err(encode(ErrorReply(kind="ClassifierError", reason="classifier queue full (1024 requests)")))
            q.drop()

    def _drain(self) -> None:
        while not self._closed.is_set():
            try:
                first = self._queue.get(timeout=0.2)
            except queue.Empty:
                continue
            batch = [first]
            while len(batch) < self.max_batch:
                try:
                    batch.append(self._queue.get_nowait())
                except queue.Empty:
                    break
            try:
                self._answer(batch)
            finally:
                for q in batch:
                    q.drop()

    def _answer(self, batch: list[Any]) -> None:
        parsed: list[tuple[Any, ClassifyRequest, bytes]] = []
        for q in batch:
            try:
                if q.attachment is None:
                    raise ProtocolError(
                        "classify needs the ClassifyRequest as the attachment and the image bytes as the payload"
                    )
                req = decode_as(ClassifyRequest, q.attachment.to_bytes(), MAX_PAYLOAD_BYTES)
                data = q.payload.to_bytes() if q.payload is not None else b""
                parsed.append((q, req, data))
            except CellError as err:
                self._reply_err(q, err)
        if not parsed:
            return
        self.batches.append(len(parsed))
        try:
            results = self.service.classify([(r, d) for _, r, d in parsed])
        except Exception as err:  # a bug must not kill the worker: every query gets an answer
            log.exception("classify batch crashed")
            for q, _, _ in parsed:
                q.reply_err(encode(ErrorReply(kind="InternalError", reason=f"{type(err).__name__}: {err}")))
            return
        for (q, _, _), res in zip(parsed, results, strict=True):
            if isinstance(res, CellError):
                self._reply_err(q, res)
            else:
                q.reply(q.key_expr, encode(res))

    @staticmethod
    def _reply_err(q: Any, err: CellError) -> None:
        log.warning("classify refused: %s", err)
        q.reply_err(encode(ErrorReply(kind=type(err).__name__, reason=str(err))))

    def close(self) -> None:
        self._queryable.undeclare()
        self._closed.set()
        self._thread.join(timeout=5.0)
        while True:  # queries that arrived but were never answered: tell their callers
            try:
                q = self._queue.get_nowait()
            except queue.Empty:
                break
            q.reply_err(encode(ErrorReply(kind="WorkerError", reason="classifier worker is shutting down")))
            q.drop()


def run_worker(cfg: CellConfig, backend: str | None, stop_event: threading.Event) -> None:
    """Serve classify until ``stop_event`` is set (blocking).

    Raises:
        ConfigError: unknown backend or no Zenoh router reachable.
    """
    from cellctl.bus.session import open_session
    from cellctl.workers._server import WorkerServer
    from cellctl.workers.classifier.enrolling import enroll_surface

    name = backend or cfg.classifier.backend
    if name not in BACKENDS:
        raise ConfigError(f"classifier backend {name!r} is unknown; expected one of {list(BACKENDS)}")
    c = cfg.classifier
    files = {s: cfg.path(p) for s in SURFACES if (p := getattr(c.detector_files, s)) is not None}
    service = ClassifierService(
        cfg.path(c.models_dir),
        c.variant,
        c.threads,
        c.decision,
        cfg.camera.max_image_pixels,
        runtime=c.runtime,
        detector_files=files,
    )
    models = service.describe()
    session = open_session(cfg, "client")
    try:
        server = BatchingClassifyServer(session, cfg.cell_id, service, c.max_batch)
        alive = WorkerServer(session, cfg.cell_id, "classifier")
        # which model decides each surface, asked before a cycle and named in its log (shipped or enrolled)
        alive.serve("models", ClassifierModelsRequest, lambda _req, _raw: service.describe())
        # a commissioning cycle enrolls each surface from its views; the new file decides from then on
        models_dir = cfg.path(c.models_dir)
        alive.serve(
            "enroll", EnrollRequest, lambda req, _raw: enroll_surface(service, req, models_dir, c.runtime, c.threads)
        )
        alive.announce()
        log.info(
            "classifier serving %s with %s",
            server.key,
            {s: f"{m.model_id} ({m.kind}, {m.path})" for s, m in models.models.items()},
        )
        try:
            stop_event.wait()
        finally:
            alive.close()
            server.close()
    finally:
        session.close()
