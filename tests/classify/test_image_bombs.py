"""Decompression bombs and truncated images: refused from the header, fast, in every decoder path."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.bus import keys
from cellctl.bus.rpc import request
from cellctl.bus.session import open_session
from cellctl.config import CellConfig
from cellctl.errors import CameraError, ClassifierError, WorkerFailed
from cellctl.images import MAX_IMAGE_PIXELS, decode_image, image_size
from cellctl.messages import ClassifyReply, ClassifyRequest
from tests.fakes.images import png_bomb

ROOT = Path(__file__).resolve().parents[2]
BOMB_SIDE = 20000


def _png(h: int, w: int) -> bytes:
    return cv2.imencode(".png", np.random.default_rng(0).integers(0, 255, (h, w, 3), dtype=np.uint8))[1].tobytes()


def test_the_bomb_is_a_real_png() -> None:
    """The generator's output decodes (at a size that fits), so the refusal below is of a real image."""
    small = png_bomb(300, 200)
    assert decode_image(small).shape == (200, 300, 3)
    assert image_size(png_bomb()) == (BOMB_SIDE, BOMB_SIDE) and len(png_bomb()) < 2_000_000


@pytest.mark.parametrize(
    "encode",
    [
        lambda img: cv2.imencode(".png", img)[1].tobytes(),
        lambda img: cv2.imencode(".jpg", img)[1].tobytes(),
        lambda img: cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes(),
    ],
    ids=["png", "jpeg", "progressive-jpeg"],
)
def test_size_is_read_from_the_header(encode) -> None:
    assert image_size(encode(np.zeros((37, 53, 3), np.uint8))) == (53, 37)


def test_a_bomb_is_refused_in_under_100_ms_and_100_mb(tmp_path: Path) -> None:
    """`cellctl classify` reads images with load_image: in a fresh process, the refusal's time and peak RSS."""
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(png_bomb())
    code = (
        "import resource, sys, time\n"
        "from cellctl.classify.data import load_image\n"
        "from cellctl.errors import ClassifierError\n"
        "load_image(sys.argv[2])  # warm the decoder's imports\n"
        "before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
        "t = time.perf_counter()\n"
        "try:\n    load_image(sys.argv[1])\nexcept ClassifierError as err:\n    print(err)\n"
        "ms = (time.perf_counter() - t) * 1000\n"
        "print(ms, (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024)\n"
    )
    good = tmp_path / "good.png"
    good.write_bytes(_png(32, 32))
    out = subprocess.run([sys.executable, "-c", code, str(bomb), str(good)], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    message, figures = out.stdout.strip().splitlines()
    ms, extra_mb = map(float, figures.split())
    assert "20000×20000 px" in message and "refused before decoding" in message
    print(f"bomb refused in {ms:.1f} ms, +{extra_mb:.1f} MB peak RSS")
    assert ms < 100 and extra_mb < 100, (ms, extra_mb)


@pytest.mark.parametrize(
    ("data", "match"),
    [
        (_png(64, 64)[:-20], "png file is truncated"),
        (cv2.imencode(".jpg", np.zeros((64, 64, 3), np.uint8))[1].tobytes()[:-300], "jpeg file is truncated"),
        (b"\x89PNG\r\n\x1a\n" + b"\0" * 40, "png header .* is missing or damaged"),
        (b"\xff\xd8\xff\xe0\x00\x02" + b"\xff\xda" + b"\0" * 20, "jpeg header .* is missing or damaged"),
        (b"\xff\xd8\xff\xd9", "jpeg header .* is missing or damaged"),
    ],
    ids=["png-truncated", "jpeg-truncated", "png-no-ihdr", "jpeg-no-sof", "jpeg-empty"],
)
def test_truncated_or_damaged_images_give_one_line(data: bytes, match: str) -> None:
    with pytest.raises(ClassifierError, match=match) as info:
        decode_image(data, "x", error=ClassifierError)
    assert "\n" not in str(info.value)


def test_the_budget_comes_from_config(cfg: CellConfig, tmp_path: Path) -> None:
    """camera.max_image_pixels bounds the folder camera (and the worker, the CLI): 64×64 over a 1024 budget."""
    from cellctl.workers.camera._folder import FolderCamera

    assert cfg.camera.max_image_pixels == MAX_IMAGE_PIXELS
    (tmp_path / "a.png").write_bytes(_png(64, 64))
    cam_cfg = cfg.camera.model_copy(update={"backend": "folder", "folder": tmp_path, "max_image_pixels": 1024})
    cam = FolderCamera(cfg.model_copy(update={"camera": cam_cfg}))
    cam.connect()
    with pytest.raises(CameraError, match=r"64×64 px \(4096 px\) by its header; the budget is 1024 px"):
        cam.capture("png")


def test_cli_classify_refuses_a_bomb_in_one_line(tmp_path: Path) -> None:
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(png_bomb())
    exe = Path(sys.executable).with_name("cellctl")
    out = subprocess.run(
        [str(exe), "classify", str(bomb), "--surface", "external", "--decision", "supervised"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert out.returncode == 2, out.stdout + out.stderr
    assert out.stdout.count("\n") == 1 and "20000×20000 px" in out.stdout and "Traceback" not in out.stderr


def test_worker_refuses_a_bomb_fast_and_answers_the_next(cfg: CellConfig, tiny_models: Path) -> None:
    import resource

    from cellctl.workers.classifier import BatchingClassifyServer, ClassifierService

    service = ClassifierService(tiny_models, "fp32", threads=1)
    bomb = png_bomb()
    with open_session(cfg, "router"), open_session(cfg, "client") as ws, open_session(cfg, "client") as cs:
        server = BatchingClassifyServer(ws, cfg.cell_id, service)
        key = keys.classifier_classify(cfg.cell_id)
        try:
            req = ClassifyRequest(surface="external")
            first, _ = request(cs, key, req, ClassifyReply, timeout=30, payload=_png(64, 64))  # warm
            before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
            t = time.perf_counter()
            with pytest.raises(WorkerFailed, match="20000×20000 px"):
                request(cs, key, req, ClassifyReply, timeout=10, payload=bomb)
            ms = (time.perf_counter() - t) * 1000
            extra_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
            again, _ = request(cs, key, req, ClassifyReply, timeout=10, payload=_png(64, 64))
            assert again.p_dirty == pytest.approx(first.p_dirty)
            print(f"worker: bomb refused in {ms:.1f} ms, +{extra_mb:.1f} MB peak RSS")
            assert ms < 100 and extra_mb < 100, (ms, extra_mb)
        finally:
            server.close()
