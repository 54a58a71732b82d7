"""The two training phases and the epoch log that keeps the best epoch over both.

:func:`train_head` (phase 1) trains the head alone on the cached pooled features;
:func:`finetune` (phase 2) trains the head with the deeper backbone stages, on cached prefix
activations or on live augmented images. Both stop early after ``Phase.patience`` epochs
without improvement; :class:`EpochLog` records every epoch (the CSV and the curves of the model
card) and keeps the weights of the best one.
"""

from __future__ import annotations

import logging
import math
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from cellctl.classify.features import FeatureCache, ImageSet, predict_dirty
from cellctl.classify.nets import backbone_parameters
from cellctl.classify.presets import Phase
from cellctl.errors import ClassifierError

__all__ = ["EpochLog", "finetune", "make_optimizer", "make_scheduler", "train_head"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())


def make_optimizer(params: list[nn.Parameter], ph: Phase) -> torch.optim.Optimizer:
    if ph.optimizer == "sgd":
        return torch.optim.SGD(params, lr=ph.lr, momentum=ph.momentum, weight_decay=ph.weight_decay)
    if ph.optimizer == "adamw":
        return torch.optim.AdamW(params, lr=ph.lr, weight_decay=ph.weight_decay)
    raise ClassifierError(f"optimizer {ph.optimizer!r} is unknown; expected 'sgd' or 'adamw'")


def make_scheduler(opt: torch.optim.Optimizer, ph: Phase) -> torch.optim.lr_scheduler.LRScheduler:
    if ph.lr_step > 0:
        return torch.optim.lr_scheduler.StepLR(opt, step_size=ph.lr_step, gamma=ph.lr_gamma)
    return torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(ph.epochs, 1))


@dataclass
class EpochLog:
    """Per-epoch metrics of both phases and the best epoch's weights.

    Attributes:
        rows: one dict per epoch (the model card's CSV).
        best_epoch: global epoch (1-based) of the best epoch, -1 before any.
        best_phase, best_val_acc, best_val_loss: its phase and validation figures.
        best_state: a copy of the model's state_dict at that epoch.
        stale: per phase, epochs in a row without improvement (early stopping).
    """

    rows: list[dict[str, Any]] = field(default_factory=list)
    best_epoch: int = -1
    best_phase: str | None = None
    best_val_acc: float = -1.0
    best_val_loss: float = math.inf
    best_state: dict[str, torch.Tensor] | None = None
    stale: dict[str, int] = field(default_factory=dict)

    def record(
        self,
        model: nn.Module,
        phase: str,
        epoch: int,
        tl: float,
        ta: float,
        vl: float,
        vacc: float,
        lr: float,
        dt: float,
    ) -> bool:
        """Log one epoch; True when it is the best so far (then its weights are kept)."""
        self.rows.append(
            {
                "phase": phase,
                "epoch": epoch,
                "global_epoch": len(self.rows) + 1,
                "lr": lr,
                "train_loss": round(tl, 5),
                "train_acc": round(ta, 5),
                "val_loss": round(vl, 5),
                "val_acc": round(vacc, 5),
                "seconds": round(dt, 2),
            }
        )
        # Keep the epoch with the best validation accuracy, the lower loss breaking ties
        # (loss alone prefers an under-fitted head whose errors are merely less confident).
        best = self.best_val_acc
        improved = vacc > best + 1e-9 or (abs(vacc - best) <= 1e-9 and vl < self.best_val_loss)
        if improved:
            self.best_val_acc, self.best_val_loss = vacc, vl
            self.best_epoch, self.best_phase = len(self.rows), phase
            self.best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        return improved

    def end_epoch(
        self,
        model: nn.Module,
        phase: str,
        epoch: int,
        n: int,
        loss_sum: float,
        correct: int,
        vl: float,
        vacc: float,
        lr: float,
        t0: float,
        patience: int,
        bar: tqdm,
    ) -> bool:
        """Record an epoch from its sums over ``n`` training samples and show it on ``bar``;
        True when ``patience`` epochs of ``phase`` in a row brought no improvement (stop early)."""
        improved = self.record(model, phase, epoch, loss_sum / n, correct / n, vl, vacc, lr, time.perf_counter() - t0)
        bar.set_postfix(val_acc=f"{vacc:.3f}", val_loss=f"{vl:.3f}")
        self.stale[phase] = 0 if improved else self.stale.get(phase, 0) + 1
        if self.stale[phase] >= patience:
            log.info("%s phase: early stop at epoch %d", phase, epoch)
            return True
        return False

    def restore_best(self, model: nn.Module) -> None:
        if self.best_state is not None:
            model.load_state_dict(self.best_state)

    def best_summary(self) -> dict[str, Any]:
        return {
            "global_epoch": self.best_epoch,
            "phase": self.best_phase,
            "val_acc": self.best_val_acc,
            "val_loss": self.best_val_loss,
        }


def train_head(
    model: nn.Module,
    head: nn.Linear,
    cache: FeatureCache,
    ph: Phase,
    rng: np.random.Generator,
    epochs: EpochLog,
    desc: str,
) -> None:
    """Phase 1: the head alone on the cached pooled features; the best epoch's weights are restored."""
    ftr, ytr, fva, yva = cache.train_features, cache.train_labels, cache.val_features, cache.val_labels
    loss_fn = nn.CrossEntropyLoss()
    opt = make_optimizer(list(head.parameters()), ph)
    sched = make_scheduler(opt, ph)
    dropout = getattr(model, "_dropout", nn.Identity())
    bar = tqdm(range(ph.epochs), desc=f"{desc} phase 1 (head)", file=sys.stderr)
    for ep in bar:
        te0 = time.perf_counter()
        head.train()
        dropout.train()
        perm = torch.from_numpy(rng.permutation(len(ytr)))
        tl, tc = 0.0, 0
        for s in range(0, len(perm), ph.batch):
            idx = perm[s : s + ph.batch]
            logits = head(dropout(ftr[idx]))
            loss = loss_fn(logits, ytr[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
            tl += loss.item() * len(idx)
            tc += int((logits.argmax(1) == ytr[idx]).sum())
        lr = opt.param_groups[0]["lr"]
        sched.step()
        head.eval()
        dropout.eval()
        with torch.inference_mode():
            vlog = head(fva)
            vl = float(loss_fn(vlog, yva))
            vacc = float((vlog.argmax(1) == yva).float().mean())
        if epochs.end_epoch(model, "head", ep + 1, len(perm), tl, tc, vl, vacc, lr, te0, ph.patience, bar):
            break
    bar.close()
    epochs.restore_best(model)


def finetune(
    model: nn.Module,
    head: nn.Linear,
    ph: Phase,
    cache: FeatureCache,
    tr: ImageSet,
    va: ImageSet,
    mean: torch.Tensor,
    std: torch.Tensor,
    rng: np.random.Generator,
    epochs: EpochLog,
    desc: str,
) -> None:
    """Phase 2: the head and the deeper backbone, on ``cache``'s prefix activations when ``ph.cached``
    (the stages from ``cache.prefix_stage`` on train) or on live augmented images (the last
    ``ph.unfreeze`` of the backbone trains); the best epoch's weights are restored."""
    loss_fn = nn.CrossEntropyLoss()
    dropout = getattr(model, "_dropout", nn.Identity())
    n_stages = len(model.stage_modules())
    k = cache.prefix_stage
    if ph.cached and (k is None or cache.train_prefix is None or cache.val_prefix is None):
        raise ClassifierError("a cached fine-tune needs the prefix activations (build_caches with prefix_stage)")
    htr, hva, yh, yhv = cache.train_prefix, cache.val_prefix, cache.train_labels, cache.val_labels
    for p in model.parameters():
        p.requires_grad_(False)
    if ph.cached:
        # Frozen prefix cached before phase 1 (cache_views augmented views); the suffix trains.
        trainable = [p for st in model.stage_modules()[k:] for m in st for p in m.parameters()]
        what = f"stages {k}-{n_stages - 1} of {n_stages} on cached activations"
    else:
        trainable = backbone_parameters(model, ph.unfreeze)
        what = f"{ph.unfreeze:.0%} of the backbone, live images"
    trainable += list(head.parameters())
    for p in trainable:
        p.requires_grad_(True)

    def forward_cached(h: torch.Tensor) -> torch.Tensor:
        return head(dropout(model.pool(model.run_stages(h, k, n_stages))))

    opt = make_optimizer(trainable, ph)
    sched = make_scheduler(opt, ph)
    bar = tqdm(range(ph.epochs), desc=f"{desc} phase 2 (fine-tune {what})", file=sys.stderr)
    for ep in bar:
        te0 = time.perf_counter()
        model.train()
        n_train = len(yh) if ph.cached else len(tr)
        perm = rng.permutation(n_train)
        tl, tc = 0.0, 0
        for s in range(0, len(perm), ph.batch):
            idx = perm[s : s + ph.batch]
            if len(idx) < 2:  # batch norm needs two samples
                continue
            if ph.cached:
                ti = torch.from_numpy(idx)
                logits, y = forward_cached(htr[ti]), yh[ti]
            else:
                x, y = tr.batch(idx, rng, mean, std)
                logits = model(x)
            loss = loss_fn(logits, y)
            opt.zero_grad()
            loss.backward()
            opt.step()
            tl += loss.item() * len(idx)
            tc += int((logits.argmax(1) == y).sum())
        lr = opt.param_groups[0]["lr"]
        sched.step()
        model.eval()
        if ph.cached:
            with torch.inference_mode():
                pv = torch.cat(
                    [torch.softmax(forward_cached(hva[i : i + 128]), 1)[:, 1] for i in range(0, len(yhv), 128)]
                ).numpy()
        else:
            pv = predict_dirty(model, va, mean, std)
        pvt = torch.from_numpy(np.stack([1 - pv, pv], 1)).clamp_min(1e-7).log()
        vl = float(nn.functional.nll_loss(pvt, torch.from_numpy(va.y)))
        vacc = float(((pv >= 0.5).astype(int) == va.y).mean())
        if epochs.end_epoch(model, "finetune", ep + 1, len(perm), tl, tc, vl, vacc, lr, te0, ph.patience, bar):
            break
    bar.close()
    epochs.restore_best(model)
