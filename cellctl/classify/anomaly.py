"""The clean-only model: what clean steel looks like, patch by patch (PatchCore-style).

Patch features come from the frozen ImageNet EfficientNet-Lite0 the project ships
(:func:`cellctl.classify.nets.lite0_imagenet_path`), tapped at three depths and brought to one
grid (:class:`PatchFeatures`): blocks 0–1 (24 ch, stride 4, average-pooled ×2), blocks 2–4
(40 ch, stride 8) and blocks 5–10 (112 ch, stride 16, upsampled ×2) — 176 channels on a 16×16
grid at 128 px input (after grey-world colour normalisation), each smoothed over its 3×3
neighbourhood (PatchCore's local aggregation) and standardised with the clean training
patches' channel statistics. The deeper blocks 11–15 are never run: the decision needs
mid-level texture, not object classes.

:class:`MemoryBank` keeps a greedy k-centre coreset of the clean training patches of one
surface (PatchCore, Roth et al. 2022; anomalib's ``KCenterGreedy`` is the reference) and scores
a patch by its distance to the nearest bank entry. Contamination of a kind no one trained on
still lands far from every clean patch, so it scores high; no gradient training is involved.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from cellctl.classify.contamination import MODEL_INPUT_PX
from cellctl.classify.nets import EfficientNetLite0, build_model

__all__ = ["FEATURE_DIM", "GRID", "INPUT_SIZE", "MemoryBank", "PatchFeatures", "greedy_coreset"]

INPUT_SIZE = MODEL_INPUT_PX
"""Detector input side (px): the image is squashed to a square, as for the supervised model."""
GREY = 0.45
"""Channel mean after grey-world normalisation."""
GRID = INPUT_SIZE // 8
"""Patch grid side (16 at 128 px): one patch = 8×8 input px."""
FEATURE_DIM = 24 + 40 + 112
MEAN = (0.5, 0.5, 0.5)
STD = (0.5, 0.5, 0.5)
"""Input normalisation of the TF EfficientNet-Lite weights ([-1, 1])."""


class PatchFeatures(nn.Module):
    """Frozen Lite0 stem + blocks 0–10 → patch features ``(N, 176, S/8, S/8)``.

    Input: RGB float ``(N, 3, S, S)`` in [0, 1], ``S`` a multiple of 32.
    """

    def __init__(self, net: EfficientNetLite0 | None = None) -> None:
        super().__init__()
        net = net if net is not None else build_model("lite0", pretrained=True)  # type: ignore[assignment]
        self.stem = nn.Sequential(net._conv_stem, net._bn0, nn.ReLU6())
        self.b01 = nn.Sequential(*net._blocks[0:2])
        self.b24 = nn.Sequential(*net._blocks[2:5])
        self.b510 = nn.Sequential(*net._blocks[5:11])
        self.register_buffer("mean", torch.tensor(MEAN).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(STD).view(1, 3, 1, 1))
        self.eval()
        for p in self.parameters():
            p.requires_grad_(False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # grey world: each channel scaled to a common mean, so a white-balance or exposure
        # change (a cabin light, a camera setting) does not move every patch away from the
        # clean bank; contamination still differs from the steel beside it
        m = x.mean(dim=(2, 3), keepdim=True).clamp_min(0.02)
        x = (x * (GREY / m)).clamp(0.0, 1.0)
        x = (x - self.mean) / self.std
        h1 = self.b01(self.stem(x))
        h2 = self.b24(h1)
        h3 = self.b510(h2)
        f = torch.cat(
            [F.avg_pool2d(h1, 2), h2, F.interpolate(h3, size=h2.shape[-2:], mode="bilinear", align_corners=False)], 1
        )
        return F.avg_pool2d(f, 3, stride=1, padding=1, count_include_pad=False)


def greedy_coreset(x: torch.Tensor, k: int, seed: int = 0, proj_dim: int = 64, fixed: int = 0) -> torch.Tensor:
    """Indices of a greedy k-centre coreset of the rows of ``x`` ``(M, D)``.

    Distances are taken in a seeded random projection to ``proj_dim`` dimensions (PatchCore's
    speed-up; Johnson–Lindenstrauss keeps the ordering roughly). Each step adds the row
    farthest from everything chosen so far, so rare clean textures (a highlight, a weld) keep
    a representative instead of being outvoted.

    ``fixed``: the first ``fixed`` rows count as chosen already (an existing bank the greedy
    continues from: site enrollment adds the new steel's patches the bank does not cover yet);
    they lead the returned indices.
    """
    m = x.shape[0]
    if k >= m:
        return torch.arange(m)
    g = torch.Generator().manual_seed(seed)
    p = torch.randn(x.shape[1], proj_dim, generator=g) / proj_dim**0.5
    z = x.float() @ p
    if fixed > 0:
        chosen = list(range(fixed))
        # chunked: 60 000 candidates × a 1024-entry bank would be a 245 MB matrix at once
        d = torch.cat([torch.cdist(z[i : i + 4096], z[:fixed]).min(1).values ** 2 for i in range(0, m, 4096)])
    else:
        first = int(torch.randint(m, (1,), generator=g))
        chosen = [first]
        d = ((z - z[first]) ** 2).sum(1)
    for _ in range(k - len(chosen)):
        i = int(torch.argmax(d))
        chosen.append(i)
        d = torch.minimum(d, ((z - z[i]) ** 2).sum(1))
    return torch.tensor(chosen)


class MemoryBank(nn.Module):
    """Clean patches of one surface; :meth:`forward` = distance of each patch to its nearest.

    Args:
        bank: ``(K, D)`` standardised clean patch features.
        mean, std: ``(D,)`` channel statistics used to standardise.
    """

    def __init__(self, bank: torch.Tensor, mean: torch.Tensor, std: torch.Tensor) -> None:
        super().__init__()
        self.register_buffer("bank", bank.float().contiguous())
        self.register_buffer("bank_sq", (bank.float() ** 2).sum(1))
        self.register_buffer("mean", mean.float().view(1, -1, 1, 1))
        self.register_buffer("std", std.float().view(1, -1, 1, 1))

    def standardise(self, f: torch.Tensor) -> torch.Tensor:
        return (f - self.mean) / self.std

    def forward(self, f: torch.Tensor) -> torch.Tensor:
        """Nearest-neighbour distance ``(N, H, W)`` of standardised patch features ``(N, D, H, W)``."""
        n, d, h, w = f.shape
        q = f.permute(0, 2, 3, 1).reshape(-1, d)
        d2 = (q * q).sum(1, keepdim=True) - 2.0 * (q @ self.bank.T) + self.bank_sq
        return d2.min(1).values.clamp_min(0).sqrt().view(n, h, w)

    @classmethod
    def fit(cls, clean: torch.Tensor, size: int, seed: int = 0, max_candidates: int = 60000) -> MemoryBank:
        """Build from raw clean patch features ``(N, D, H, W)``: statistics, then a coreset of
        ``size`` patches out of at most ``max_candidates`` (seeded random subset)."""
        d = clean.shape[1]
        flat = clean.permute(0, 2, 3, 1).reshape(-1, d).float()
        mean, std = flat.mean(0), flat.std(0).clamp_min(1e-4)
        z = (flat - mean) / std
        if z.shape[0] > max_candidates:
            rng = np.random.default_rng(seed)
            z = z[torch.from_numpy(rng.choice(z.shape[0], max_candidates, replace=False))]
        idx = greedy_coreset(z, size, seed)
        return cls(z[idx], mean, std)
