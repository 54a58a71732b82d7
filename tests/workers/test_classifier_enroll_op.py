"""The classifier worker's ``enroll`` op (a commissioning cycle's enrollment): the shipped detector is the
base, the file is written where the request says, and it decides the surface's next views at once."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.classify.enroll import MIN_IMAGES
from cellctl.config import project_root
from cellctl.errors import ClassifierError
from cellctl.hashing import file_sha256
from cellctl.messages import ClassifyRequest, EnrollRequest
from cellctl.workers.classifier import ClassifierService
from cellctl.workers.classifier.enrolling import enroll_surface

SHIPPED = project_root() / "models" / "classifier"


def _views(folder: Path, n: int) -> None:
    from cellctl.classify.contamination import closeup_steel

    rng = np.random.default_rng(7)
    for i in range(n):
        p = folder / "plan-1" / f"{i:04d}.png"
        p.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(p), (closeup_steel("external", 96, 96, rng) * 255).astype(np.uint8))


@pytest.fixture(scope="module")
def service() -> ClassifierService:
    return ClassifierService(SHIPPED, decision="detector", runtime="torch", threads=1)


def test_enroll_writes_the_file_and_the_surface_is_decided_by_it(service, tmp_path: Path) -> None:
    before = service.describe().models["external"]
    assert before.kind == "detector"
    _views(tmp_path / "external", MIN_IMAGES)
    out = tmp_path / "external.enrolled.pt"
    reply = enroll_surface(
        service, EnrollRequest(surface="external", images=str(tmp_path / "external"), out=str(out)), SHIPPED, "torch", 1
    )
    assert reply.model_id.startswith("external-enrolled-") and reply.images == MIN_IMAGES
    assert reply.sha256 == file_sha256(out) and reply.path == str(out)
    now = service.describe().models["external"]
    assert now.kind == "enrolled" and now.model_id == reply.model_id and now.path == str(out)
    assert service.describe().models["internal"].kind == "detector"  # the other surface keeps its detector
    png = (tmp_path / "external" / "plan-1" / "0000.png").read_bytes()
    (r,) = service.classify([(ClassifyRequest(surface="external", format="png"), png)])
    assert not isinstance(r, Exception) and r.model_id == reply.model_id


def test_too_few_views_are_refused_and_the_detector_in_use_stays(service, tmp_path: Path) -> None:
    in_use = service.describe().models["internal"].model_id
    _views(tmp_path / "internal", MIN_IMAGES - 1)
    out = tmp_path / "internal.enrolled.pt"
    req = EnrollRequest(surface="internal", images=str(tmp_path / "internal"), out=str(out))
    with pytest.raises(ClassifierError, match=f"at least {MIN_IMAGES}"):
        enroll_surface(service, req, SHIPPED, "torch", 1)
    assert not out.exists() and service.describe().models["internal"].model_id == in_use


@pytest.mark.slow  # ~50 s: the worker traces every detector at start, then one real enrollment
def test_the_worker_serves_enroll_over_zenoh_and_its_models_op_follows(tmp_path: Path, port: int) -> None:
    """The op as a commissioning cycle calls it (real Zenoh loopback): enrolled, then named by ``models``;
    a refused enrollment is an error reply naming the count."""
    import threading
    import time

    from cellctl.bus import keys
    from cellctl.bus.rpc import request
    from cellctl.bus.session import open_session
    from cellctl.config import load_config
    from cellctl.errors import WorkerFailed
    from cellctl.messages import ClassifierModels, ClassifierModelsRequest, EnrollReply
    from cellctl.workers.classifier import run_worker
    from tests.conftest import cfg_overrides

    cfg = load_config(None, [*cfg_overrides(tmp_path, port), "classifier.runtime=torch", "classifier.threads=1"])
    _views(tmp_path / "ok" / "external", MIN_IMAGES)
    _views(tmp_path / "few" / "external", 3)
    stop = threading.Event()
    with open_session(cfg, "router"):
        t = threading.Thread(target=run_worker, args=(cfg, None, stop), daemon=True)
        t.start()
        try:
            with open_session(cfg, "client") as cs:
                deadline = time.monotonic() + 120  # detectors traced on shared cores
                while not list(cs.liveliness().get(keys.alive(cfg.cell_id, "classifier"), timeout=1)):
                    if time.monotonic() > deadline or not t.is_alive():
                        pytest.fail("classifier worker never announced itself")
                    stop.wait(0.2)
                op = keys.worker_op(cfg.cell_id, "classifier", "enroll")
                few = EnrollRequest(
                    surface="external", images=str(tmp_path / "few" / "external"), out=str(tmp_path / "x.pt")
                )
                with pytest.raises(WorkerFailed, match=f"at least {MIN_IMAGES}"):
                    request(cs, op, few, EnrollReply, timeout=30, role="classifier")
                out = tmp_path / "ok" / "external.enrolled.pt"
                req = EnrollRequest(surface="external", images=str(tmp_path / "ok" / "external"), out=str(out))
                reply, _ = request(cs, op, req, EnrollReply, timeout=300, role="classifier")
                key = keys.worker_op(cfg.cell_id, "classifier", "models")
                models, _ = request(cs, key, ClassifierModelsRequest(), ClassifierModels, timeout=10)
                assert models.models["external"].kind == "enrolled" and models.models["external"].path == str(out)
                assert models.models["external"].model_id == reply.model_id and not (tmp_path / "x.pt").exists()
        finally:
            stop.set()
            t.join(10)
