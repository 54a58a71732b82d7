"""Evaluation of a clean/dirty model: accuracy, confusion, false-clean rate, ROC AUC, threshold.

Conventions: label 1 = dirty is the positive class; a *false clean* is a dirty image called
clean (the costly error: a dirty bin goes back into production). The decision rule (dirty
at ``p_dirty >= threshold``, *uncertain* within a logit band) is :mod:`cellctl.classify.decision`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from cellctl.classify.decision import is_uncertain, logit
from cellctl.errors import ClassifierError

__all__ = ["choose_threshold", "evaluate_folder", "metrics", "roc_auc", "roc_curve"]


def roc_curve(p: ArrayLike, y: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """False-positive rate, true-positive rate and thresholds (descending), dirty = positive."""
    p = np.asarray(p, np.float64)
    y = np.asarray(y).astype(int)
    order = np.argsort(-p, kind="stable")
    ps, ys = p[order], y[order]
    distinct = np.r_[np.where(np.diff(ps))[0], len(ps) - 1]
    tps = np.cumsum(ys)[distinct]
    fps = (1 + distinct) - tps
    P, N = max(int(ys.sum()), 1), max(int(len(ys) - ys.sum()), 1)
    return np.r_[0.0, fps / N], np.r_[0.0, tps / P], np.r_[np.inf, ps[distinct]]


def roc_auc(p: ArrayLike, y: ArrayLike) -> float | None:
    """Area under the ROC curve (Mann–Whitney, ties count ½); None if one class is absent."""
    p = np.asarray(p, np.float64)
    y = np.asarray(y).astype(int)
    pos, neg = p[y == 1], p[y == 0]
    if len(pos) == 0 or len(neg) == 0:
        return None
    from scipy.stats import rankdata

    ranks = rankdata(np.r_[pos, neg])
    return float((ranks[: len(pos)].sum() - len(pos) * (len(pos) + 1) / 2) / (len(pos) * len(neg)))


def choose_threshold(p: ArrayLike, y: ArrayLike, target_false_clean: float, cap: float = 0.5) -> float:
    """Decision threshold whose false-clean rate on ``(p, y)`` is at most the target.

    With ``m = floor(target · n_dirty)`` misses allowed, ``t_fc`` is the ``m``-th lowest
    ``p_dirty`` among dirty images (at most ``m`` fall below it). The threshold is placed
    half-way, in logit space, between ``t_fc`` and the highest clean score below it: the same
    decisions on this set, with the widest margin on both sides for new data (a threshold set
    right at the lowest dirty score would let slightly fainter powder through). It is never
    above ``cap``: a threshold is lowered for safety, never raised past 0.5 to buy fewer false
    alarms.

    Raises:
        ClassifierError: no dirty images, or a target outside [0, 1).
    """
    if not 0.0 <= target_false_clean < 1.0:
        raise ClassifierError(f"target false-clean rate {target_false_clean!r} must be in [0, 1)")
    p = np.asarray(p, np.float64)
    y = np.asarray(y).astype(int)
    dirty = np.sort(p[y == 1])
    if len(dirty) == 0:
        raise ClassifierError("cannot choose a threshold without dirty images")
    m = int(math.floor(target_false_clean * len(dirty)))
    t_fc = float(dirty[m])
    below = p[(y == 0) & (p < t_fc)]
    c_max = float(below.max()) if len(below) else 0.0
    t = float(1.0 / (1.0 + np.exp(-(logit(c_max) + logit(t_fc)) / 2.0)))
    t = min(t, float(np.nextafter(t_fc, 0.0)))  # the m-th dirty image itself stays dirty
    return float(min(max(t, 1e-4), cap))


def metrics(p: ArrayLike, y: ArrayLike, threshold: float, band: float) -> dict[str, Any]:
    """All figures of one evaluation (see module doc for the conventions)."""
    p = np.asarray(p, np.float64)
    y = np.asarray(y).astype(int)
    pred = (p >= threshold).astype(int)
    tn = int(((pred == 0) & (y == 0)).sum())
    fp = int(((pred == 1) & (y == 0)).sum())
    fn = int(((pred == 0) & (y == 1)).sum())
    tp = int(((pred == 1) & (y == 1)).sum())
    n_dirty, n_clean = tp + fn, tn + fp
    unc = is_uncertain(p, threshold, band)
    certain = ~unc
    return {
        "n": int(len(y)),
        "accuracy": round((tp + tn) / max(len(y), 1), 5),
        "confusion": {"clean_as_clean": tn, "clean_as_dirty": fp, "dirty_as_clean": fn, "dirty_as_dirty": tp},
        "false_clean_rate": round(fn / n_dirty, 5) if n_dirty else None,
        "false_dirty_rate": round(fp / n_clean, 5) if n_clean else None,
        "roc_auc": None if (a := roc_auc(p, y)) is None else round(a, 5),
        "threshold": threshold,
        "uncertain_fraction": round(float(unc.mean()), 5) if len(y) else 0.0,
        "accuracy_certain": round(float((pred[certain] == y[certain]).mean()), 5) if certain.any() else None,
        "false_clean_certain": int(((pred == 0) & (y == 1) & certain).sum()),
    }


def evaluate_folder(
    model_path: Path | str,
    data: Path | str,
    surface: str,
    *,
    split: str = "auto",
    target_false_clean: float = 0.01,
    variant: str = "fp32",
    png: Path | str | None = None,
) -> dict[str, Any]:
    """Evaluate a weights file on a dataset folder.

    Args:
        model_path: ``models/classifier/<surface>.pt``.
        data: dataset root.
        surface: which surface folder/model.
        split: ``test`` = the held-out part of the split the model card records (same seed);
            ``all`` = every image (a separate test set such as the shifted one); ``auto`` =
            ``test`` when ``data`` is the folder the model was trained on, else ``all``.
        target_false_clean: for the informative "threshold for this target on this set".
        variant: ``fp32`` or ``fast`` (see :class:`cellctl.classify.infer.SurfaceModel`).
        png: optional path for a ROC + score-histogram figure.
    """
    from cellctl.classify.data import split_dataset
    from cellctl.classify.infer import SurfaceModel

    model = SurfaceModel.load(model_path, surface=surface, variant=variant)
    if split == "auto":
        trained_on = Path(str(model.card.get("data", {}).get("root", ""))) if model.card else None
        split = "test" if trained_on is not None and trained_on == Path(data).resolve() else "all"
    if split == "test":
        seed = int(model.card.get("data", {}).get("split_seed", 0)) if model.card else 0
        items = split_dataset(data, surface, seed=seed).test
    elif split == "all":
        items = split_dataset(data, surface, fractions=(0.0, 0.0, 1.0)).test
    else:
        raise ClassifierError(f"split {split!r} is unknown; expected 'auto', 'test' or 'all'")
    from cellctl.classify.data import load_image

    p = model.predict_proba([load_image(path) for path, _ in items])
    y = np.array([lab for _, lab in items])
    out = metrics(p, y, model.threshold, model.band)
    out["split"] = split
    out["model_id"] = model.model_id
    out["variant"] = variant
    dirty_present = bool((y == 1).any())
    out["threshold_for_target_on_this_set"] = (
        choose_threshold(p, y, target_false_clean, cap=1.0) if dirty_present else None
    )
    out["target_false_clean"] = target_false_clean
    if png:
        _plot(p, y, model.threshold, Path(png), f"{surface} {model.model_id} ({split})")
    return out


def _plot(p: np.ndarray, y: np.ndarray, threshold: float, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fpr, tpr, _ = roc_curve(p, y)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.8))
    a1.plot(fpr, tpr)
    a1.plot([0, 1], [0, 1], "k:", lw=0.8)
    a1.set_xlabel("false-dirty rate (clean called dirty)")
    a1.set_ylabel("dirty detection rate (1 − false-clean)")
    a1.set_title(f"ROC, AUC {roc_auc(p, y) or float('nan'):.4f}")
    bins = np.linspace(0, 1, 41)
    a2.hist(p[y == 0], bins, alpha=0.6, label="clean")
    a2.hist(p[y == 1], bins, alpha=0.6, label="dirty")
    a2.axvline(threshold, color="k", ls="--", label=f"threshold {threshold:.3f}")
    a2.set_yscale("log")
    a2.set_xlabel("p_dirty")
    a2.legend()
    fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
