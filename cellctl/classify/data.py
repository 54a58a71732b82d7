"""Datasets for the clean/dirty classifier: ImageFolder layout, split, statistics, augmentation.

Layout: ``DATA/<surface>/<clean|dirty>/*.png`` (``.jpg``/``.jpeg`` also read). The split is
reproducible: files are sorted, then shuffled with ``numpy.random.default_rng(seed)`` per
class (stratified), so the same folder and seed always give the same train/val/test lists.

Images are read with OpenCV (RGB, uint8), resized to the model input (``INTER_AREA``), and
normalised with per-channel mean/std computed on train+val (as the paper does).

Augmentation (train only): random pad-and-crop (reflect pad 1/16 of the side, then crop back:
a translation that never cuts a powder spot out of the frame, so labels stay true), horizontal
and vertical flips (a bin wall has no preferred up/down at the scale of one view), brightness
×U(0.8, 1.2) and contrast ×U(0.8, 1.2) (exposure varies from view to view), and Gaussian
sensor noise σ ~ U(0, 4) grey levels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from cellctl.classify.collect import LABELS, SURFACES, check_surface
from cellctl.errors import ClassifierError
from cellctl.images import MAX_IMAGE_PIXELS, decode_image

__all__ = [
    "IMAGE_EXTS",
    "Split",
    "augment",
    "channel_stats",
    "list_dataset",
    "load_image",
    "prepare",
    "split_dataset",
]

IMAGE_EXTS = (".png", ".jpg", ".jpeg")


def load_image(path: Path | str, max_pixels: int = MAX_IMAGE_PIXELS) -> NDArray[np.uint8]:
    """Read an image file as RGB uint8 ``(H, W, 3)``.

    Args:
        path: the PNG/JPEG file.
        max_pixels: pixel budget checked from the header before decoding (``camera.max_image_pixels``).

    Raises:
        ClassifierError: the file is missing, not a usable image or over the pixel budget.
    """
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as err:
        raise ClassifierError(f"image file {str(p)!r} cannot be read: {err}") from err
    return decode_image(data, repr(str(p)), error=ClassifierError, max_pixels=max_pixels)


def prepare(img: NDArray[np.uint8], size: int) -> NDArray[np.float32]:
    """Resize an RGB uint8 image to ``size``×``size`` and scale to [0, 1], layout ``(3, H, W)``."""
    if img.shape[0] != size or img.shape[1] != size:
        shrink = img.shape[0] > size and img.shape[1] > size
        img = cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    return np.ascontiguousarray(img.transpose(2, 0, 1), dtype=np.float32) / np.float32(255.0)


def augment(x: NDArray[np.float32], rng: np.random.Generator) -> NDArray[np.float32]:
    """Training augmentation of one prepared image ``(3, S, S)`` in [0, 1] (see module doc)."""
    _, s, _ = x.shape
    pad = max(1, s // 16)
    img = np.pad(x, ((0, 0), (pad, pad), (pad, pad)), mode="reflect")
    dy, dx = rng.integers(0, 2 * pad + 1, size=2)
    img = img[:, dy : dy + s, dx : dx + s]
    if rng.random() < 0.5:
        img = img[:, :, ::-1]
    if rng.random() < 0.5:
        img = img[:, ::-1, :]
    mean = img.mean()
    img = (img - mean) * rng.uniform(0.8, 1.2) + mean * rng.uniform(0.8, 1.2)
    sigma = rng.uniform(0.0, 4.0) / 255.0
    if sigma > 0:
        img = img + rng.normal(0.0, sigma, size=img.shape).astype(np.float32)
    return np.clip(img, 0.0, 1.0).astype(np.float32)


@dataclass
class Split:
    """A reproducible train/val/test split of one surface's images (labels 0 clean, 1 dirty)."""

    root: Path
    surface: str
    seed: int
    train: list[tuple[Path, int]] = field(default_factory=list)
    val: list[tuple[Path, int]] = field(default_factory=list)
    test: list[tuple[Path, int]] = field(default_factory=list)

    def counts(self) -> dict[str, dict[str, int]]:
        out = {}
        for name in ("train", "val", "test"):
            items = getattr(self, name)
            out[name] = {lab: sum(1 for _, y in items if y == i) for i, lab in enumerate(LABELS)}
        return out


def list_dataset(root: Path | str, surface: str) -> list[tuple[Path, int]]:
    """All ``(path, label)`` of ``root/<surface>/<clean|dirty>/``, sorted by path.

    Raises:
        ClassifierError: unknown surface, missing folder, or fewer than 2 images of a class
            (a one-class dataset cannot train or evaluate a binary classifier).
    """
    check_surface(surface)
    base = Path(root) / surface
    if not base.is_dir():
        raise ClassifierError(
            f"dataset folder {str(base)!r} does not exist; expected DATA/<surface>/<clean|dirty>/*.png "
            f"with surface one of {list(SURFACES)}"
        )
    items: list[tuple[Path, int]] = []
    for label, name in enumerate(LABELS):
        files = (
            sorted(p for p in (base / name).glob("*") if p.suffix.lower() in IMAGE_EXTS)
            if (base / name).is_dir()
            else []
        )
        if len(files) < 2:
            raise ClassifierError(
                f"dataset {str(base)!r} has {len(files)} '{name}' image(s); expected at least 2 per class "
                f"in {str(base / name)!r} (a one-class dataset cannot train a clean/dirty classifier)"
            )
        items.extend((p, label) for p in files)
    return items


def split_dataset(
    root: Path | str,
    surface: str,
    *,
    seed: int = 0,
    fractions: tuple[float, float, float] = (0.7, 0.15, 0.15),
) -> Split:
    """Stratified reproducible split (see module doc).

    Args:
        fractions: train, val, test; must sum to 1. A fraction of 0 leaves that part empty
            (``(0, 0, 1)`` = everything is test, used to evaluate a separate test folder).
    """
    if abs(sum(fractions) - 1.0) > 1e-6 or min(fractions) < 0:
        raise ClassifierError(f"split fractions {fractions} must be non-negative and sum to 1")
    items = list_dataset(root, surface)
    split = Split(Path(root), surface, seed)
    rng = np.random.default_rng(seed)
    for label in range(len(LABELS)):
        files = [p for p, y in items if y == label]
        order = rng.permutation(len(files))
        n = len(files)
        n_train = int(round(n * fractions[0]))
        n_val = int(round(n * fractions[1])) if fractions[2] > 0 else n - n_train
        for k, idx in enumerate(order):
            part = split.train if k < n_train else split.val if k < n_train + n_val else split.test
            part.append((files[idx], label))
    return split


def channel_stats(paths: list[Path], size: int) -> tuple[list[float], list[float]]:
    """Per-channel mean and std (RGB, [0, 1] scale) over images resized to ``size``."""
    if not paths:
        raise ClassifierError("cannot compute channel statistics of an empty image list")
    s1 = np.zeros(3)
    s2 = np.zeros(3)
    n = 0
    for p in paths:
        x = prepare(load_image(p), size).reshape(3, -1).astype(np.float64)
        s1 += x.sum(1)
        s2 += (x * x).sum(1)
        n += x.shape[1]
    mean = s1 / n
    std = np.sqrt(np.maximum(s2 / n - mean * mean, 1e-8))
    return [float(v) for v in mean], [float(v) for v in std]
