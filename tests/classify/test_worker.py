"""Classifier worker over a real Zenoh loopback: answers, refuses bad input, keeps serving, batches."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.bus import keys
from cellctl.bus.rpc import request
from cellctl.bus.session import open_session
from cellctl.config import CellConfig
from cellctl.errors import WorkerFailed
from cellctl.messages import ClassifyReply, ClassifyRequest
from cellctl.workers.classifier import BatchingClassifyServer, ClassifierService, run_worker


def _png(seed: int) -> bytes:
    img = np.random.default_rng(seed).integers(0, 255, (64, 64, 3), dtype=np.uint8)
    return cv2.imencode(".png", img)[1].tobytes()


@pytest.fixture
def router(cfg: CellConfig):
    with open_session(cfg, "router") as s:
        yield s


def test_worker_serves_refuses_and_keeps_serving(cfg: CellConfig, router, tiny_models: Path, tmp_path: Path) -> None:
    only_external = tmp_path / "m"
    only_external.mkdir()
    for suffix in (".pt", ".json"):
        (only_external / f"external{suffix}").write_bytes((tiny_models / f"external{suffix}").read_bytes())
    service = ClassifierService(only_external, "fp32", threads=1)
    assert "internal" in service.problems
    with open_session(cfg, "client") as ws, open_session(cfg, "client") as cs:
        server = BatchingClassifyServer(ws, cfg.cell_id, service)
        try:
            key = keys.classifier_classify(cfg.cell_id)
            _wait_served(cs, key)
            rep, _ = request(cs, key, ClassifyRequest(surface="external"), ClassifyReply, timeout=10, payload=_png(0))
            assert rep.label in ("clean", "dirty") and rep.model_id.startswith("external-lite0-")
            with pytest.raises(WorkerFailed, match="cannot be decoded"):
                request(
                    cs,
                    key,
                    ClassifyRequest(surface="external"),
                    ClassifyReply,
                    timeout=10,
                    payload=b"garbage!",
                )
            with pytest.raises(WorkerFailed, match="empty"):
                request(cs, key, ClassifyRequest(surface="external"), ClassifyReply, timeout=10, payload=b"")
            with pytest.raises(WorkerFailed, match="no model for surface 'internal'.*do not exist"):
                request(cs, key, ClassifyRequest(surface="internal"), ClassifyReply, timeout=10, payload=_png(1))
            small = cv2.imencode(".png", np.zeros((4, 4, 3), np.uint8))[1].tobytes()
            with pytest.raises(WorkerFailed, match="4×4 px"):
                request(cs, key, ClassifyRequest(surface="external"), ClassifyReply, timeout=10, payload=small)
            # a request without the image attachment layout (JSON payload only)
            with pytest.raises(WorkerFailed, match="attachment"):
                request(cs, key, ClassifyRequest(surface="external"), ClassifyReply, timeout=10)
            # an unknown surface never passes the typed message
            bad = b'{"type":"cellctl/ClassifyRequest","v":1,"surface":"roof","format":"png"}'
            replies = list(cs.get(key, payload=_png(2), attachment=bad, timeout=10))
            assert replies[0].ok is None and b"surface" in replies[0].err.payload.to_bytes()
            rep2, _ = request(cs, key, ClassifyRequest(surface="external"), ClassifyReply, timeout=10, payload=_png(0))
            assert rep2.p_dirty == pytest.approx(rep.p_dirty)
        finally:
            server.close()


def _wait_served(session, key: str) -> None:
    """Until the server's queryable has reached the client through the router (any reply will do)."""
    deadline = time.monotonic() + 10
    while not list(session.get(key, timeout=1.0)):
        assert time.monotonic() < deadline, f"nobody serves {key} after 10 s"
        time.sleep(0.05)


def test_queued_requests_are_batched(cfg: CellConfig, router, tiny_models: Path) -> None:
    service = ClassifierService(tiny_models, "fp32", threads=1)
    with open_session(cfg, "client") as ws, open_session(cfg, "client") as cs:
        server = BatchingClassifyServer(ws, cfg.cell_id, service, max_batch=8)
        key = keys.classifier_classify(cfg.cell_id)
        try:
            _wait_served(cs, key)
            server.batches.clear()
            service._lock.acquire()  # hold the model so that the next requests queue up
            surfaces = ["external", "internal"] * 4

            def one(i: int) -> ClassifyReply:
                return request(
                    cs, key, ClassifyRequest(surface=surfaces[i]), ClassifyReply, timeout=20, payload=_png(i)
                )[0]

            with ThreadPoolExecutor(8) as pool:
                futs = [pool.submit(one, i) for i in range(8)]
                threading.Event().wait(1.0)  # let all 8 queries reach the worker's queue
                service._lock.release()
                replies = [f.result() for f in futs]
            assert [r.model_id.split("-")[0] for r in replies] == surfaces
            assert sum(server.batches) == 8 and max(server.batches) > 1
        finally:
            server.close()


def test_run_worker_announces_and_stops(cfg: CellConfig, router, tiny_models: Path) -> None:
    # the whole-image models only (tiny_models has no detector; the shipped default decision is the detector)
    c = cfg.classifier.model_copy(update={"models_dir": tiny_models, "decision": "supervised"})
    cfg2 = cfg.model_copy(update={"classifier": c})
    stop = threading.Event()
    t = threading.Thread(target=run_worker, args=(cfg2, None, stop), daemon=True)
    t.start()
    with open_session(cfg, "client") as cs:
        alive = keys.alive(cfg.cell_id, "classifier")
        deadline = time.monotonic() + 60  # loading + freezing two models takes seconds on shared cores
        while not list(cs.liveliness().get(alive, timeout=1)):
            if time.monotonic() > deadline or not t.is_alive():
                pytest.fail("classifier worker never announced itself")
            stop.wait(0.2)
        rep, _ = request(
            cs,
            keys.classifier_classify(cfg.cell_id),
            ClassifyRequest(surface="internal"),
            ClassifyReply,
            timeout=10,
            payload=_png(3),
        )
        assert rep.model_id.startswith("internal-lite0-") and rep.model_id.endswith("-fused")
    stop.set()
    t.join(10)
    assert not t.is_alive()
