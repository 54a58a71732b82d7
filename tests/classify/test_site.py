"""The unseen-site generator: seeded, labelled by the one visibility rule, and not the training steel."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.classify.contamination import closeup_steel
from cellctl.classify.site import SITE_FAMILIES, site_dataset, site_draw, site_steel
from cellctl.errors import ClassifierError


def _images(root: Path, surface: str) -> dict[str, np.ndarray]:
    return {p.relative_to(root).as_posix(): cv2.imread(str(p)) for p in sorted((root / surface).rglob("*.png"))}


def test_site_dataset_is_deterministic_per_seed(tmp_path: Path) -> None:
    """Same seed: byte-identical images and masks; another seed: other images."""
    a = site_dataset(tmp_path / "a", "internal", 3, 3, seed=5, size=96)
    b = site_dataset(tmp_path / "b", "internal", 3, 3, seed=5, size=96)
    site_dataset(tmp_path / "c", "internal", 3, 3, seed=6, size=96)
    assert a["counts"] == {"clean": 3, "dirty": 3} and a["by_family"] == b["by_family"]
    ia, ib = _images(tmp_path / "a", "internal"), _images(tmp_path / "b", "internal")
    ic = _images(tmp_path / "c", "internal")
    assert list(ia) == list(ib) and all(np.array_equal(ia[k], ib[k]) for k in ia)
    assert len(list((tmp_path / "a" / "internal" / "masks").glob("*.png"))) == 3
    assert not all(np.array_equal(x, y) for x, y in zip(ia.values(), ic.values(), strict=True))


@pytest.mark.parametrize("surface", ["external", "internal"])
def test_site_steel_differs_from_training_steel(surface: str) -> None:
    """The site's clean steel is not the training close-up: its grain has no direction (external)
    or its texture statistics lie outside the training draws (internal)."""

    def stats(img: np.ndarray) -> tuple[float, float]:
        g = cv2.cvtColor((img * 255).astype(np.uint8), cv2.COLOR_RGB2GRAY).astype(np.float32)
        gx, gy = cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1)
        # structure-tensor coherence: 1 = one grain direction, 0 = isotropic
        jxx, jyy, jxy = (gx * gx).mean(), (gy * gy).mean(), (gx * gy).mean()
        coh = float(np.sqrt((jxx - jyy) ** 2 + 4 * jxy**2) / (jxx + jyy + 1e-6))
        return coh, float(np.percentile(g, 99) - np.percentile(g, 50))

    rng = np.random.default_rng(0)
    train = [stats(closeup_steel(surface, 128, 128, rng)) for _ in range(12)]
    site = [stats(site_steel(surface, 128, 128, rng)[0]) for _ in range(12)]
    if surface == "external":
        # brushed training steel is strongly directional; bead-blasted/orbital is not
        assert np.median([c for c, _ in site]) < 0.5 * np.median([c for c, _ in train])
    else:
        # the electropolished mirror's tube reflections: bright thin bars over a darker base
        assert np.median([s for _, s in site]) > np.median([s for _, s in train]) + 30


def test_site_draw_labels_dirt_and_clean() -> None:
    """A clean draw has an empty mask; a dirty draw's mask marks visible contamination of a site family."""
    rng = np.random.default_rng(3)
    rgb, mask, label, info = site_draw(False, "external", 96, rng)
    assert label == "clean" and mask.max() == 0 and rgb.dtype == np.uint8
    for _ in range(20):
        d = site_draw(True, "external", 96, rng)
        if d is not None:
            break
    assert d is not None
    _, mask, label, info = d
    assert label == "dirty" and mask.mean() >= 0.003
    assert all(f in SITE_FAMILIES for f in info["family"].split("+"))


def test_site_dataset_refuses_bad_arguments(tmp_path: Path) -> None:
    with pytest.raises(ClassifierError, match="'elsewhere'"):
        site_dataset(tmp_path, "external", 2, 2, site="elsewhere")
    with pytest.raises(ClassifierError, match="clean=0 dirty=0"):
        site_dataset(tmp_path, "external", 0, 0)
