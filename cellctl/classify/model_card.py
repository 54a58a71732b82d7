"""What training writes beside ``out`` (e.g. ``models/classifier/external.pt``).

``external.pt`` (fp16 weights + what the loader needs, :func:`save_model`), ``external.json``
(the model card, :func:`model_card`), ``external.csv`` (per-epoch metrics) and ``external.png``
(accuracy curves like paper Fig. 16), both from :func:`write_card_files`.
"""

from __future__ import annotations

import csv
import datetime as _dt
import json
import os
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch
from torch import nn

from cellctl.classify.calibration import Calibration
from cellctl.classify.infer import WEIGHTS_FORMAT
from cellctl.classify.nets import describe
from cellctl.classify.phases import EpochLog
from cellctl.classify.presets import Phase, Preset
from cellctl.hashing import file_sha256

__all__ = ["AUGMENTATION", "model_card", "phase_record", "save_model", "write_card_files"]

AUGMENTATION = "reflect pad-crop 1/16, h/v flip, brightness/contrast x0.8-1.2, noise sigma 0-4"
"""What :func:`cellctl.classify.data.augment` does, as the card states it."""


def save_model(model: nn.Module, path: Path, meta: dict[str, Any]) -> None:
    """Write the weights file: fp16 state_dict + the metadata needed to run it (atomic)."""
    sd = {k: (v.half() if v.is_floating_point() else v) for k, v in model.state_dict().items()}
    blob = {"format": WEIGHTS_FORMAT, **meta, "state_dict": sd}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(blob, tmp)
    os.replace(tmp, path)


def phase_record(ph: Phase, *, cached: bool) -> dict[str, Any]:
    """A phase as the card records it, ``cached`` stating what the phase actually trained on."""
    return {**asdict(ph), "cached": cached}


def _provenance(folder: Path) -> list[dict[str, Any]] | None:
    """The ``synth.json`` runs that made a dataset folder (None for collected data)."""
    p = folder / "synth.json"
    try:
        return json.loads(p.read_text()) if p.is_file() else None
    except json.JSONDecodeError:
        return None


def model_card(
    *,
    out: Path,
    meta: dict[str, Any],
    preset: str,
    ps: Preset,
    head: Phase,
    finetune: Phase,
    model: nn.Module,
    backbone_src: str,
    backbone_sha: str | None,
    data: Path | str,
    surface: str,
    seed: int,
    counts: dict[str, Any],
    target_false_clean: float,
    epochs: EpochLog,
    cal: Calibration,
    train_s: float,
) -> dict[str, Any]:
    """The model card of the weights just written to ``out`` (JSON-able)."""
    sha = file_sha256(out)
    return {
        "model_id": f"{surface}-{ps.arch}-{sha[:12]}",
        "weights": out.name,
        "sha256": sha,
        "bytes": out.stat().st_size,
        "weights_dtype": "float16 (run in float32)",
        **meta,
        "decision": {
            "rule": "dirty if p_dirty >= threshold",
            "target_false_clean": target_false_clean,
            "uncertain": f"|logit(p_dirty) - logit(threshold)| < {cal.band}",
        },
        "preset": preset,
        # Phase 1 always trains the head on cached pooled features (cellctl.classify.features);
        # the fine-tune is cached only when its Phase says so.
        "phases": {"head": phase_record(head, cached=True), "finetune": phase_record(finetune, cached=finetune.cached)},
        "cache_views": ps.cache_views,
        "backbone": {"source": backbone_src, "sha256": backbone_sha, **describe(model)},
        "data": {
            "root": str(Path(data).resolve()),
            "split_seed": seed,
            "counts": counts,
            "synth": _provenance(Path(data) / surface),
            "augmentation": AUGMENTATION,
        },
        "seed": seed,
        "best_epoch": epochs.best_summary(),
        "metrics": {"val": cal.val, "test": cal.test},
        "train_seconds": round(train_s, 1),
        "torch": torch.__version__,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    }


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


def write_card_files(out: Path, card: dict[str, Any], rows: list[dict[str, Any]], title: str) -> None:
    """The card (``.json``), the per-epoch CSV and, when any epoch ran, the curves (``.png``) beside ``out``."""
    out.with_suffix(".json").write_text(json.dumps(card, indent=2) + "\n")
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()) if rows else ["phase"])
        w.writeheader()
        w.writerows(rows)
    if rows:
        _plot(rows, out.with_suffix(".png"), title)
