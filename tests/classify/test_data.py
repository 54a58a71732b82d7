"""Image decoding, dataset listing and splitting."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.classify.data import augment, channel_stats, list_dataset, load_image, prepare, split_dataset
from cellctl.errors import ClassifierError
from cellctl.images import decode_image


def _png(img: np.ndarray) -> bytes:
    ok, enc = cv2.imencode(".png", img)
    assert ok
    return enc.tobytes()


def test_decode_png_is_rgb() -> None:
    bgr = np.zeros((20, 30, 3), np.uint8)
    bgr[..., 2] = 200  # red in BGR
    rgb = decode_image(_png(bgr))
    assert rgb.shape == (20, 30, 3)
    assert rgb[0, 0, 0] == 200 and rgb[0, 0, 2] == 0


@pytest.mark.parametrize(
    ("data", "match"),
    [
        (b"", "empty"),
        (b"\x89PNG\r\n\x1a\nbroken", "cannot be decoded"),
        (b"hello world", "cannot be decoded"),
    ],
)
def test_bad_bytes_are_refused(data: bytes, match: str) -> None:
    with pytest.raises(ClassifierError, match=match):
        decode_image(data, error=ClassifierError)


def test_wrong_sizes_are_refused_and_grey_is_accepted() -> None:
    with pytest.raises(ClassifierError, match=r"is 8×8 px; expected sides between 16"):
        decode_image(_png(np.zeros((8, 8, 3), np.uint8)), error=ClassifierError)
    grey = decode_image(_png(np.full((32, 32), 90, np.uint8)))
    assert grey.shape == (32, 32, 3)


def test_load_image_reports_classifier_errors(tmp_path: Path) -> None:
    """The dataset reader decodes with the shared decoder and keeps the classifier's error family."""
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\nbroken")
    with pytest.raises(ClassifierError, match="bad.png.*cannot be decoded"):
        load_image(bad)
    good = tmp_path / "good.png"
    good.write_bytes(_png(np.full((20, 24, 3), (10, 20, 30), np.uint8)))
    assert load_image(good)[0, 0].tolist() == [30, 20, 10]


def test_prepare_and_augment_shapes() -> None:
    img = np.random.default_rng(0).integers(0, 255, (100, 80, 3), dtype=np.uint8)
    x = prepare(img, 64)
    assert x.shape == (3, 64, 64) and x.dtype == np.float32 and 0 <= x.min() and x.max() <= 1
    y = augment(x, np.random.default_rng(0))
    assert y.shape == x.shape and 0 <= y.min() and y.max() <= 1


def _make(root: Path, surface: str, n_clean: int, n_dirty: int) -> None:
    for label, n in (("clean", n_clean), ("dirty", n_dirty)):
        d = root / surface / label
        d.mkdir(parents=True, exist_ok=True)
        for i in range(n):
            cv2.imwrite(str(d / f"{i}.png"), np.full((20, 20, 3), i * 10 % 255, np.uint8))


def test_split_is_reproducible_stratified_and_disjoint(tmp_path: Path) -> None:
    _make(tmp_path, "external", 20, 20)
    a = split_dataset(tmp_path, "external", seed=5)
    b = split_dataset(tmp_path, "external", seed=5)
    c = split_dataset(tmp_path, "external", seed=6)
    assert a.train == b.train and a.test == b.test
    assert a.train != c.train
    sets = [set(p for p, _ in part) for part in (a.train, a.val, a.test)]
    assert sum(map(len, sets)) == 40 and not (sets[0] & sets[1]) and not (sets[1] & sets[2])
    assert a.counts() == {
        "train": {"clean": 14, "dirty": 14},
        "val": {"clean": 3, "dirty": 3},
        "test": {"clean": 3, "dirty": 3},
    }
    mean, std = channel_stats([p for p, _ in a.train], 16)
    assert len(mean) == 3 and all(s > 0 for s in std)


def test_one_class_empty_or_unknown_surface_datasets_are_refused(tmp_path: Path) -> None:
    _make(tmp_path, "internal", 5, 0)
    with pytest.raises(ClassifierError, match="0 'dirty' image.*one-class"):
        list_dataset(tmp_path, "internal")
    with pytest.raises(ClassifierError, match="does not exist"):
        list_dataset(tmp_path, "external")
    with pytest.raises(ClassifierError, match="surface 'side' is unknown"):
        list_dataset(tmp_path, "side")
