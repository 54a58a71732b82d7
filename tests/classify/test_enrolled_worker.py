"""A site-enrolled detector in the cell: config ``classifier.detector_files`` → the classifier worker
(real Zenoh on loopback) → its ``models`` op, its replies, a cycle's result and MCAP metadata."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.bus import keys
from cellctl.bus.rpc import request
from cellctl.bus.session import open_session
from cellctl.classify.enroll import MIN_IMAGES, enroll_detector, save_enrolled
from cellctl.classify.fusion import Detector
from cellctl.config import load_config, project_root
from cellctl.errors import ClassifierError, ConfigError
from cellctl.messages import (
    ClassifierModels,
    ClassifierModelsRequest,
    ClassifyReply,
    ClassifyRequest,
    CycleOutcome,
    ViewpointResult,
)
from cellctl.workers.classifier import ClassifierService, run_worker
from tests.conftest import cfg_overrides

SHIPPED = project_root() / "models" / "classifier"


def _steel(n: int, seed: int) -> list[np.ndarray]:
    from cellctl.classify.contamination import closeup_steel

    rng = np.random.default_rng(seed)
    return [(closeup_steel("external", 96, 96, rng) * 255).astype(np.uint8) for _ in range(n)]


@pytest.fixture(scope="module")
def enrolled_file(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A project folder with ``config/cell.yaml`` naming ``site/external.enrolled.pt`` (relative)."""
    root = tmp_path_factory.mktemp("plant")
    paths = []
    for i, im in enumerate(_steel(MIN_IMAGES, 4)):
        p = root / "clean" / f"{i}.png"
        p.parent.mkdir(exist_ok=True)
        cv2.imwrite(str(p), im)
        paths.append(p)
    base = Detector.load(SHIPPED / "external.detect.pt", surface="external")
    det = enroll_detector(base, paths, "external", dirt_per_image=1, site_bank=64, progress=None)
    save_enrolled(det, root / "site" / "external.enrolled.pt")
    (root / "config").mkdir()
    (root / "config" / "cell.yaml").write_text(
        f"classifier:\n  models_dir: {SHIPPED}\n  detector_files:\n    external: site/external.enrolled.pt\n"
    )
    return root, det.model_id


def test_config_names_enrolled_files_relative_to_the_project_and_refuses_unknown_surfaces(
    enrolled_file: tuple[Path, str],
) -> None:
    root, _ = enrolled_file
    cfg = load_config(root / "config" / "cell.yaml")
    assert cfg.path(cfg.classifier.detector_files.external) == root / "site" / "external.enrolled.pt"
    assert cfg.classifier.decision == "detector" and cfg.classifier.detector_files.internal is None
    with pytest.raises(ConfigError, match="unknown key 'classifier.detector_files.extrenal'"):
        load_config(root / "config" / "cell.yaml", ["classifier.detector_files.extrenal=x.pt"])
    with pytest.raises(ConfigError, match="decision is 'supervised'"):
        load_config(root / "config" / "cell.yaml", ["classifier.decision=supervised"])


def test_a_missing_enrolled_file_stops_the_service_instead_of_falling_back(tmp_path: Path) -> None:
    with pytest.raises(ClassifierError, match="gone.pt"):
        ClassifierService(SHIPPED, threads=1, decision="detector", detector_files={"external": tmp_path / "gone.pt"})


def test_worker_loads_the_enrolled_file_names_it_and_decides_with_it(
    enrolled_file: tuple[Path, str], tmp_path: Path, port: int
) -> None:
    root, model_id = enrolled_file
    cfg = load_config(root / "config" / "cell.yaml", cfg_overrides(tmp_path, port))
    stop = threading.Event()
    with open_session(cfg, "router"):
        t = threading.Thread(target=run_worker, args=(cfg, None, stop), daemon=True)
        t.start()
        try:
            with open_session(cfg, "client") as cs:
                alive = keys.alive(cfg.cell_id, "classifier")
                deadline = time.monotonic() + 90  # three detectors traced on shared cores
                while not list(cs.liveliness().get(alive, timeout=1)):
                    if time.monotonic() > deadline or not t.is_alive():
                        pytest.fail("classifier worker never announced itself")
                    stop.wait(0.2)
                key = keys.worker_op(cfg.cell_id, "classifier", "models")
                models, _ = request(cs, key, ClassifierModelsRequest(), ClassifierModels, timeout=10)
                ext, inn = models.models["external"], models.models["internal"]
                assert (ext.kind, ext.model_id) == ("enrolled", model_id)
                assert ext.path == str(root / "site" / "external.enrolled.pt")
                assert ext.enrolled_on and ext.enrolled_on["source"]["images"] == MIN_IMAGES
                assert inn.kind == "detector" and inn.model_id.startswith("internal-detect-")
                png = cv2.imencode(".png", _steel(1, 9)[0])[1].tobytes()
                rep, _ = request(
                    cs, keys.classifier_classify(cfg.cell_id), ClassifyRequest(surface="external"), ClassifyReply,
                    timeout=20, payload=png,
                )  # fmt: skip
                assert rep.model_id == model_id and rep.heatmap is not None
        finally:
            stop.set()
            t.join(10)


def test_a_cycle_result_and_its_log_name_the_models_that_decided(tmp_path: Path) -> None:
    """The reply's model id rides on each view into CycleResult.classifier_models and the MCAP's
    ``result`` metadata (the recorder as the supervisor closes a cycle)."""
    import datetime as dt

    from mcap.reader import make_reader

    from cellctl.recording.index import CycleIndex
    from cellctl.supervisor.context import CycleContext
    from cellctl.supervisor.recorder import CycleRecorder, NullRecorder, assemble_result
    from cellctl.supervisor.steps.classifying import with_reply

    cfg = load_config(None, cfg_overrides(tmp_path, 7999))
    ctx = CycleContext(cycle_id="c-enrolled", cfg=cfg, session=None, log=NullRecorder())
    replies = [
        ClassifyReply(label="clean", p_dirty=0.1, model_id="external-enrolled-0123456789ab"),
        ClassifyReply(label="dirty", p_dirty=0.9, model_id="external-enrolled-0123456789ab"),
        ClassifyReply(label="clean", p_dirty=0.2, model_id="internal-detect-253d95cac5d8"),
    ]
    ctx.scan.viewpoints = [with_reply(ViewpointResult(index=i), r) for i, r in enumerate(replies)]
    result = assemble_result(ctx, CycleOutcome.completed)
    assert result.classifier_models == ["external-enrolled-0123456789ab", "internal-detect-253d95cac5d8"]
    assert [v.model_id for v in result.viewpoints] == [r.model_id for r in replies]
    rec = CycleRecorder(cfg, CycleIndex(tmp_path / "cells.db"), "c-enrolled", dt.datetime.now(dt.UTC), "evaluate")
    rec.close(result)
    with open(rec.path, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert meta["result"]["classifier_models"] == "external-enrolled-0123456789ab,internal-detect-253d95cac5d8"


def test_a_result_cut_for_the_wire_still_names_its_models() -> None:
    """Views' model ids go with their heat maps when a result is too large (the MCAP keeps both);
    ``classifier_models`` stays on the wire."""
    from cellctl.bus.codec import decode_as, encode
    from cellctl.messages import CycleResult
    from cellctl.supervisor.publisher import fit_to_wire

    mid = "internal-enrolled-0123456789ab"
    views = [ViewpointResult(index=i, label="clean", p_dirty=0.01, heatmap="x" * 600, model_id=mid) for i in range(170)]
    res = CycleResult(cycle_id="c1", outcome="completed", verdict="clean", viewpoints=views, classifier_models=[mid])
    assert len(encode(res)) > 64 * 1024
    got = decode_as(CycleResult, fit_to_wire(res))
    assert len(got.viewpoints) == 170 and all(v.heatmap is None and v.model_id is None for v in got.viewpoints)
    assert got.classifier_models == [mid]
