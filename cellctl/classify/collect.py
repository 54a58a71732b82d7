"""Data collection for the classifier (light: numpy/OpenCV only, safe to import in the daemon).

In the cycle's ``collect`` mode (start params ``mode=collect, label=clean|dirty``) the
supervisor stores every captured image under ``<dataset>/<surface>/<label>/<cycle>_<k>.png``
with :func:`store_capture`, building exactly the ImageFolder layout that ``cellctl train``
reads.
"""

from __future__ import annotations

import os
import re
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from cellctl.errors import ClassifierError
from cellctl.images import IMAGE_MAGIC, MAX_IMAGE_PIXELS, check_budget, decode_image, encode_image
from cellctl.surface import SURFACES, Surface
from cellctl.surface import check_surface as _check_surface

__all__ = [
    "DATASET_NAME",
    "LABELS",
    "SURFACES",
    "capture_path",
    "check_label",
    "check_surface",
    "store_capture",
    "store_image",
]

# SURFACES (re-exported from cellctl.surface): one network each (external matt/brushed, internal glossy/polished)
LABELS = ("clean", "dirty")
"""Class names in index order: 0 = clean, 1 = dirty."""

DATASET_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
"""A dataset the PLC may name (Start param ``dataset``): a plain folder name under
``classifier.dataset_dir``, never a path — the PLC must not choose where the daemon writes."""
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")


def check_surface(surface: str) -> Surface:
    """Return ``surface`` if known, else raise ClassifierError listing the allowed ones."""
    return _check_surface(surface, ClassifierError)


def check_label(label: str) -> str:
    """Return ``label`` if it is ``clean`` or ``dirty``, else raise ClassifierError."""
    if label not in LABELS:
        raise ClassifierError(f"label {label!r} is unknown; expected one of {list(LABELS)}")
    return label


def capture_path(dataset: Path | str, surface: str, label: str, cycle_id: str, k: int) -> Path:
    """Where image ``k`` of cycle ``cycle_id`` goes: ``<dataset>/<surface>/<label>/<cycle>_<k>.png``."""
    check_surface(surface)
    check_label(label)
    if not _NAME.match(cycle_id or ""):
        raise ClassifierError(f"cycle id {cycle_id!r} is not usable in a file name; expected letters, digits, _.-")
    if not isinstance(k, int) or k < 0:
        raise ClassifierError(f"viewpoint index {k!r} must be a non-negative integer")
    return Path(dataset) / surface / label / f"{cycle_id}_{k:03d}.png"


def store_capture(
    dataset: Path | str,
    surface: str,
    label: str,
    cycle_id: str,
    k: int,
    image: bytes,
    max_pixels: int = MAX_IMAGE_PIXELS,
) -> Path:
    """Store one captured image for training; PNG bytes are written as is, JPEG is re-encoded to PNG.

    The write is atomic (temporary file + rename), so a crash never leaves a truncated PNG
    that would later break training.

    Args:
        dataset: dataset root (the ``DATA`` of ``DATA/<surface>/<label>/``).
        surface: ``external`` or ``internal``.
        label: ``clean`` or ``dirty`` (given by the operator at Start).
        cycle_id: the cycle's id (file-name safe).
        k: viewpoint index in the cycle.
        image: encoded PNG or JPEG bytes from the camera worker.
        max_pixels: the pixel budget (``camera.max_image_pixels``): a JPEG is decoded under it, a
            PNG's header is checked against it.

    Returns:
        The path written.

    Raises:
        ClassifierError: bad surface/label/id, empty or non-image bytes, over the pixel budget.
    """
    path = capture_path(dataset, surface, label, cycle_id, k)
    if not image:
        raise ClassifierError(f"image for {path.name} is empty (0 bytes); expected PNG or JPEG bytes")
    if image.startswith(IMAGE_MAGIC["png"]):
        # stored as is, but checked like a decode: training would otherwise meet the bomb later
        check_budget(image, f"for {path.name} (PNG)", ClassifierError, max_pixels)
        data = bytes(image)
    elif image.startswith(IMAGE_MAGIC["jpeg"]):
        rgb = decode_image(image, f"for {path.name} (JPEG)", error=ClassifierError, max_pixels=max_pixels)
        data = encode_image(rgb, "png", ClassifierError)
    else:
        raise ClassifierError(f"image for {path.name} starts {bytes(image[:8])!r}; expected PNG or JPEG bytes")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".png")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except OSError as err:
        Path(tmp).unlink(missing_ok=True)
        raise ClassifierError(f"cannot write {str(path)!r}: {err}") from err
    return path


def store_image(cfg: Any, params: Mapping[str, Any], surface: str, cycle_id: str, k: int, image: bytes) -> Path:
    """The supervisor's collect-mode hook: store one capture with the operator's label.

    Args:
        cfg: the cell config (``classifier.dataset_dir`` is the default dataset root,
            resolved against the project root).
        params: the Start command's params: ``label`` (``clean``/``dirty``, required) and an
            optional ``dataset`` name: a sub-folder of the dataset root (the supervisor has
            checked it is a plain name, not a path).
        surface, cycle_id, k, image: as :func:`store_capture`.

    Raises:
        ClassifierError: missing/unknown label or a bad image (see :func:`store_capture`).
    """
    label = params.get("label")
    if not isinstance(label, str):
        raise ClassifierError(f"collect mode needs start param label 'clean' or 'dirty', got {label!r}")
    root = cfg.path(cfg.classifier.dataset_dir)
    name = params.get("dataset")
    if name is not None and not (isinstance(name, str) and DATASET_NAME.fullmatch(name)):
        raise ClassifierError(f"dataset {name!r:.80} is not a plain folder name under {str(root)!r}")
    return store_capture(root / name if name else root, surface, label, cycle_id, k, image, cfg.camera.max_image_pixels)
