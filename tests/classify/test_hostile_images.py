"""Hostile images (part of the hostile-client suite, `make test-all`): bombs and truncations.

Every decoder path refuses them in one line, quickly, and the classifier worker keeps serving.
"""

from __future__ import annotations

import random
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.bus import keys
from cellctl.bus.rpc import request
from cellctl.bus.session import open_session
from cellctl.config import CellConfig
from cellctl.errors import CameraError, CellError, ClassifierError, WorkerFailed
from cellctl.images import decode_image
from cellctl.messages import ClassifyReply, ClassifyRequest
from tests.fakes.images import jpeg_claiming, png_bomb, png_claiming

pytestmark = pytest.mark.slow


def _good(fmt: str) -> bytes:
    img = np.random.default_rng(5).integers(0, 255, (64, 64, 3), dtype=np.uint8)
    return cv2.imencode(".png" if fmt == "png" else ".jpg", img)[1].tobytes()


def _hostile() -> list[tuple[str, bytes]]:
    rng = random.Random(32)
    cases = [
        ("png bomb 20000x20000", png_bomb()),
        ("png claiming 65535x65535", png_claiming(65535, 65535)),
        ("png claiming 2^31 x 1", png_claiming(2**31 - 1, 1)),
        ("png claiming 0x0", png_claiming(0, 0)),
        ("jpeg claiming 65500x65500", jpeg_claiming(65500, 65500)),
        ("jpeg claiming 0 height", jpeg_claiming(64, 0)),
    ]
    for fmt in ("png", "jpeg"):
        good = _good(fmt)
        for cut in sorted(rng.sample(range(1, len(good) - 2), 8)):
            cases.append((f"{fmt} cut at {cut}/{len(good)}", good[:cut]))
    return cases


HOSTILE = _hostile()


@pytest.mark.parametrize(("name", "data"), HOSTILE, ids=[n for n, _ in HOSTILE])
def test_decoder_refuses_in_one_line_and_fast(name: str, data: bytes) -> None:
    t = time.perf_counter()
    with pytest.raises(ClassifierError) as info:
        decode_image(data, name, error=ClassifierError)
    ms = (time.perf_counter() - t) * 1000
    assert "\n" not in str(info.value) and ms < 100, (str(info.value), ms)


def test_folder_camera_refuses_each_and_keeps_capturing(cfg: CellConfig, tmp_path: Path) -> None:
    from cellctl.workers.camera._folder import FolderCamera

    for i, (_, data) in enumerate(HOSTILE[:6]):
        (tmp_path / f"{i:02d}-bad.png").write_bytes(data)
    (tmp_path / "99-good.png").write_bytes(_good("png"))
    cam = FolderCamera(cfg.model_copy(update={"camera": cfg.camera.model_copy(update={"folder": tmp_path})}))
    cam.connect()
    for _ in range(6):
        with pytest.raises(CameraError):
            cam.capture("png")
    reply, data = cam.capture("png")
    assert data == _good("png")


def test_classifier_worker_survives_every_hostile_image(cfg: CellConfig, tiny_models: Path) -> None:
    from cellctl.workers.classifier import BatchingClassifyServer, ClassifierService

    service = ClassifierService(tiny_models, "fp32", threads=1)
    with open_session(cfg, "router"), open_session(cfg, "client") as ws, open_session(cfg, "client") as cs:
        server = BatchingClassifyServer(ws, cfg.cell_id, service)
        key = keys.classifier_classify(cfg.cell_id)
        req = ClassifyRequest(surface="external")
        try:
            first, _ = request(cs, key, req, ClassifyReply, timeout=30, payload=_good("png"))
            for name, data in HOSTILE:
                t = time.perf_counter()
                with pytest.raises(WorkerFailed) as info:
                    request(cs, key, req, ClassifyReply, timeout=10, payload=data)
                assert (time.perf_counter() - t) < 1.0 and "\n" not in str(info.value), name
                again, _ = request(cs, key, req, ClassifyReply, timeout=10, payload=_good("png"))
                assert again.p_dirty == pytest.approx(first.p_dirty), name
        finally:
            server.close()


def test_every_refusal_is_a_cell_error() -> None:
    """No hostile image escapes as a cv2.error, ValueError or MemoryError."""
    for name, data in HOSTILE:
        try:
            decode_image(data, name)
        except CellError:
            continue
        pytest.fail(f"{name} was decoded")
