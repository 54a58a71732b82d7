"""Images held in memory for training, model outputs on them, and the feature caches.

Phase 1 trains only the head on a frozen backbone. Because the frozen backbone runs in eval
mode, its pooled features do not change during the phase, so they are computed once
("feature caching") for ``cache_views`` augmented views of every training image and for the
validation images; the head then trains on the cached features in seconds instead of
re-running the backbone every epoch. A cached fine-tune (``Phase.cached``) uses the same trick
one level down: activations of the frozen shallower stages are cached once and only the deeper
stages train (on 2 shared cores a live Lite0 training step costs 100-170 ms per image, the
cached suffix step a few ms).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from cellctl.classify.data import augment, load_image, prepare

__all__ = ["CACHE_SPLIT", "FeatureCache", "ImageSet", "build_caches", "logit_margins", "predict_dirty"]

CACHE_SPLIT = {"lite0": 9, "resnet18": 4}
"""First trainable stage of the cached fine-tune: Lite0 blocks 8-15 + head conv (stride-16
stages onward, 80×8×8 activations cached at 128 px); ResNet18 layer4."""


class ImageSet:
    """All images of a split part, prepared once (uint8 in memory: 48 kB each at 128 px)."""

    def __init__(self, items: list[tuple[Path, int]], size: int, desc: str) -> None:
        self.x = np.empty((len(items), 3, size, size), np.uint8)
        self.y = np.array([y for _, y in items], np.int64)
        for i, (p, _) in enumerate(tqdm(items, desc=f"load {desc}", file=sys.stderr, leave=False)):
            self.x[i] = np.round(prepare(load_image(p), size) * 255.0).astype(np.uint8)

    def __len__(self) -> int:
        return len(self.y)

    def batch(
        self, idx: np.ndarray, rng: np.random.Generator | None, mean: torch.Tensor, std: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Normalised images ``idx`` (augmented when ``rng`` is given) and their labels."""
        xs = self.x[idx].astype(np.float32) / 255.0
        if rng is not None:
            xs = np.stack([augment(x, rng) for x in xs])
        t = (torch.from_numpy(np.ascontiguousarray(xs)) - mean) / std
        return t, torch.from_numpy(self.y[idx])


def _per_batch(fn, model: nn.Module, data: ImageSet, mean: torch.Tensor, std: torch.Tensor, bs: int) -> np.ndarray:
    """``fn(model(x))`` over the plain images of ``data`` in batches (eval mode), concatenated."""
    model.eval()
    out = []
    with torch.inference_mode():
        for s in range(0, len(data), bs):
            x, _ = data.batch(np.arange(s, min(s + bs, len(data))), None, mean, std)
            out.append(fn(model(x)).numpy())
    return np.concatenate(out) if out else np.zeros(0)


def predict_dirty(model: nn.Module, data: ImageSet, mean: torch.Tensor, std: torch.Tensor, bs: int = 64) -> np.ndarray:
    """Softmax ``p_dirty`` of every image of ``data``."""
    return _per_batch(lambda logits: torch.softmax(logits, 1)[:, 1], model, data, mean, std, bs)


def logit_margins(model: nn.Module, data: ImageSet, mean: torch.Tensor, std: torch.Tensor, bs: int = 64) -> np.ndarray:
    """Logit margins ``z = logit_dirty − logit_clean`` (``p_dirty = sigmoid(z / T)``), float64."""
    return _per_batch(lambda logits: logits[:, 1].double() - logits[:, 0].double(), model, data, mean, std, bs)


def _views(
    fn, data: ImageSet, mean: torch.Tensor, std: torch.Tensor, rng: np.random.Generator | None, views: int, desc: str
) -> tuple[torch.Tensor, torch.Tensor]:
    """``fn(batch)`` over ``views`` passes of ``data``: view 0 plain, further views augmented."""
    outs, labels = [], []
    with torch.inference_mode():
        for v in range(views):
            for s in tqdm(range(0, len(data), 64), desc=f"{desc} view {v + 1}/{views}", file=sys.stderr, leave=False):
                idx = np.arange(s, min(s + 64, len(data)))
                x, y = data.batch(idx, rng if (v > 0 and rng is not None) else None, mean, std)
                outs.append(fn(x))
                labels.append(y)
    return torch.cat(outs), torch.cat(labels)


@dataclass
class FeatureCache:
    """What the backbone computed once for both phases.

    Attributes:
        train_features, train_labels: pooled features of ``cache_views`` views of every training
            image (the head phase trains on these).
        val_features, val_labels: pooled features of the plain validation images.
        prefix_stage: first trainable stage of a cached fine-tune (None: the fine-tune, if any,
            runs live).
        train_prefix, val_prefix: activations after the frozen stages ``[0, prefix_stage)``,
            same views and order as the features (None when ``prefix_stage`` is None).
    """

    train_features: torch.Tensor
    train_labels: torch.Tensor
    val_features: torch.Tensor
    val_labels: torch.Tensor
    prefix_stage: int | None = None
    train_prefix: torch.Tensor | None = None
    val_prefix: torch.Tensor | None = None

    def drop_features(self) -> None:
        """Free the pooled features once the head phase is done (the prefix stays for phase 2)."""
        self.train_features = self.val_features = torch.empty(0)

    def drop_prefix(self) -> None:
        """Free the prefix activations once the fine-tune is done."""
        self.train_prefix = self.val_prefix = None


def build_caches(
    model: nn.Module,
    tr: ImageSet,
    va: ImageSet,
    mean: torch.Tensor,
    std: torch.Tensor,
    rng: np.random.Generator,
    *,
    views: int,
    prefix_stage: int | None,
) -> FeatureCache:
    """Run the frozen backbone once: pooled features for the head, and prefix activations when
    ``prefix_stage`` is given (then the pooled features are the frozen suffix applied to them,
    so one backbone pass serves both phases)."""
    model.eval()
    if prefix_stage is None:
        ftr, ytr = _views(model.features, tr, mean, std, rng, views, "features train")
        fva, yva = _views(model.features, va, mean, std, None, 1, "features val")
        return FeatureCache(ftr, ytr, fva, yva)
    k, n_stages = prefix_stage, len(model.stage_modules())
    htr, yh = _views(lambda x: model.run_stages(x, 0, k), tr, mean, std, rng, views, "prefix train")
    hva, yhv = _views(lambda x: model.run_stages(x, 0, k), va, mean, std, None, 1, "prefix val")
    htr, hva = htr.clone(), hva.clone()
    with torch.inference_mode():
        ftr = torch.cat([model.pool(model.run_stages(htr[i : i + 256], k, n_stages)) for i in range(0, len(yh), 256)])
        fva = torch.cat([model.pool(model.run_stages(hva[i : i + 256], k, n_stages)) for i in range(0, len(yhv), 256)])
    return FeatureCache(ftr, yh, fva, yhv, prefix_stage=k, train_prefix=htr, val_prefix=hva)
