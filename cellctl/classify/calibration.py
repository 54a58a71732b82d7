"""Calibration of a trained model: temperature on validation, then the decision threshold.

Temperature scaling keeps the ranking (AUC) and only makes ``p_dirty`` honest, so that a
threshold and an ``uncertain`` band chosen on validation data mean the same on new data
(:mod:`cellctl.classify.decision`). :func:`calibrate_splits` runs at the end of training;
:func:`calibrate` refits a trained model file in place (``cellctl eval --recalibrate``).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import nn

from cellctl.classify.data import split_dataset
from cellctl.classify.decision import UNCERTAIN_LOGIT_BAND
from cellctl.classify.evaluate import choose_threshold, metrics
from cellctl.classify.features import ImageSet, logit_margins
from cellctl.classify.nets import build_model
from cellctl.errors import ClassifierError
from cellctl.hashing import file_sha256

__all__ = ["Calibration", "calibrate", "calibrate_splits", "fit_temperature"]


def fit_temperature(z: np.ndarray, y: np.ndarray) -> float:
    """Temperature ``T`` minimising the NLL of ``sigmoid(z / T)`` (grid over 1–50, log-spaced).

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


class Calibration(NamedTuple):
    """What :func:`calibrate_splits` fitted and measured."""

    temperature: float
    threshold: float
    band: float
    val: dict[str, Any]
    test: dict[str, Any]


def calibrate_splits(
    model: nn.Module, va: ImageSet, te: ImageSet, mean: torch.Tensor, std: torch.Tensor, target: float
) -> Calibration:
    """Temperature and threshold (for false-clean rate ``target``) from validation; metrics on
    validation and test."""
    zv = logit_margins(model, va, mean, std)
    temperature = fit_temperature(zv, va.y)
    pv = 1.0 / (1.0 + np.exp(-zv / temperature))
    threshold = choose_threshold(pv, va.y, target)
    band = UNCERTAIN_LOGIT_BAND
    pt = 1.0 / (1.0 + np.exp(-logit_margins(model, te, mean, std) / temperature))
    return Calibration(
        temperature, threshold, band, metrics(pv, va.y, threshold, band), metrics(pt, te.y, threshold, band)
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
    va, te = ImageSet(split.val, size, "val"), ImageSet(split.test, size, "test")
    mean = torch.tensor(blob["mean"]).view(1, 3, 1, 1)
    std = torch.tensor(blob["std"]).view(1, 3, 1, 1)
    cal = calibrate_splits(model, va, te, mean, std, target_false_clean)
    blob.update(threshold=cal.threshold, temperature=cal.temperature, uncertain_logit_band=cal.band)
    tmp = path.with_suffix(".pt.tmp")
    torch.save(blob, tmp)
    os.replace(tmp, path)
    sha = file_sha256(path)
    card.update(
        model_id=f"{blob['surface']}-{blob['arch']}-{sha[:12]}",
        sha256=sha,
        bytes=path.stat().st_size,
        threshold=cal.threshold,
        temperature=cal.temperature,
        uncertain_logit_band=cal.band,
        metrics={"val": cal.val, "test": cal.test},
        calibrated=_dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    )
    card["decision"]["target_false_clean"] = target_false_clean
    card_path.write_text(json.dumps(card, indent=2) + "\n")
    return card
