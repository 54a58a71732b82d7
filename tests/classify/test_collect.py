"""Collect mode storage (light module, no torch)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.classify.collect import capture_path, store_capture
from cellctl.errors import ClassifierError


def test_store_png_and_jpeg(tmp_path: Path) -> None:
    img = np.random.default_rng(0).integers(0, 255, (24, 24, 3), dtype=np.uint8)
    png = cv2.imencode(".png", img)[1].tobytes()
    jpg = cv2.imencode(".jpg", img)[1].tobytes()
    p1 = store_capture(tmp_path, "external", "dirty", "c-001", 0, png)
    p2 = store_capture(tmp_path, "internal", "clean", "c-001", 7, jpg)
    assert p1 == tmp_path / "external" / "dirty" / "c-001_000.png"
    assert p1.read_bytes() == png
    assert p2 == capture_path(tmp_path, "internal", "clean", "c-001", 7)
    assert cv2.imread(str(p2)).shape == (24, 24, 3)
    assert not list(tmp_path.rglob(".tmp-*"))


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (("external", "greasy", "c1", 0, b"\x89PNG\r\n\x1a\n"), "label 'greasy' is unknown"),
        (("top", "clean", "c1", 0, b"\x89PNG\r\n\x1a\n"), "surface 'top' is unknown"),
        (("external", "clean", "../x", 0, b"\x89PNG\r\n\x1a\n"), "not usable in a file name"),
        (("external", "clean", "c1", -1, b"\x89PNG\r\n\x1a\n"), "non-negative"),
        (("external", "clean", "c1", 0, b""), "empty"),
        (("external", "clean", "c1", 0, b"GIF89a...."), "expected PNG or JPEG"),
    ],
)
def test_bad_collect_input(tmp_path: Path, args: tuple, match: str) -> None:
    with pytest.raises(ClassifierError, match=match):
        store_capture(tmp_path, *args)


def test_collect_module_does_not_import_torch() -> None:
    """The supervisor may import cellctl.classify.collect: it must stay light."""
    code = "import sys, cellctl.classify.collect; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_store_image_supervisor_hook(tmp_path: Path) -> None:
    """The supervisor's call: dataset from config (or params), label from the Start params."""
    from cellctl.classify.collect import store_image
    from cellctl.config import load_config

    cfg = load_config(None, [f"classifier.dataset_dir={tmp_path / 'ds'}"])
    png = cv2.imencode(".png", np.zeros((20, 20, 3), np.uint8))[1].tobytes()
    cid = "20261127T064512-123-1"
    p = store_image(cfg, {"mode": "collect", "label": "clean"}, "internal", cid, 3, png)
    assert p == tmp_path / "ds" / "internal" / "clean" / f"{cid}_003.png"
    p2 = store_image(cfg, {"label": "dirty", "dataset": "other"}, "external", cid, 0, png)
    assert p2.parent == tmp_path / "ds" / "other" / "external" / "dirty"
    with pytest.raises(ClassifierError, match="not a plain folder name"):
        store_image(cfg, {"label": "dirty", "dataset": "../../etc"}, "external", cid, 0, png)
    with pytest.raises(ClassifierError, match="needs start param label"):
        store_image(cfg, {"mode": "collect"}, "external", cid, 0, png)


def test_a_capture_over_the_pixel_budget_is_not_stored(tmp_path: Path) -> None:
    """Collect mode stores a PNG as is: its header is checked against camera.max_image_pixels first (a bomb
    in the dataset would otherwise reach the decoder at training time), and a JPEG decodes under it."""
    from tests.fakes.images import jpeg_claiming, png_claiming

    img = np.random.default_rng(0).integers(0, 255, (24, 32, 3), dtype=np.uint8)
    png = cv2.imencode(".png", img)[1].tobytes()
    jpg = cv2.imencode(".jpg", img)[1].tobytes()
    for bomb in (png_claiming(20000, 20000), jpeg_claiming(20000, 20000)):
        with pytest.raises(ClassifierError, match="by its header; the budget is"):
            store_capture(tmp_path, "external", "clean", "c-1", 0, bomb)
    for data in (png, jpg):
        with pytest.raises(ClassifierError, match=f"24 px \\({24 * 32} px\\).*the budget is {24 * 32 - 1} px"):
            store_capture(tmp_path, "external", "clean", "c-1", 1, data, max_pixels=24 * 32 - 1)
    assert not list(tmp_path.rglob("*.png"))
    assert store_capture(tmp_path, "external", "clean", "c-1", 2, png, max_pixels=24 * 32).read_bytes() == png
