"""Choose the visible-mask surroundings factor on a held-out draw of the *training* generator.

``cellctl detector label-check --surface S [--n-dirty 300 --n-clean 150 --seed 11]``

Draws dirty and clean images exactly as ``cellctl dataset contam`` does (same families, optics and
twin renders; a seed no data set uses, never the shifted generator), labels every layered dirty
draw under each candidate :data:`~cellctl.classify.contamination.CLUTTER_K` (0 = the reference-only
rule of earlier rounds), and scores the images with a detector trained *before* the rule changed
(``models/classifier/S.detect.pt`` unless ``--model``): a single-image observer. For each candidate
it reports how many draws keep a dirty label (the rest would be redrawn), the observer's ROC AUC
and its clean specificity at the threshold that keeps 99 % of the dirty images (the 1 %
false-clean operating point). A rule that labels only what can be seen in the image lets the
observer separate the classes; a rule that removes too much discards visible dirt. The JSON goes
to ``--out``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from cellctl.classify.collect import check_surface
from cellctl.classify.contam_dataset import _draw
from cellctl.classify.contamination import FAMILIES, MODEL_INPUT_PX, VISIBLE_ALPHA, visible_mask
from cellctl.classify.evaluate import roc_auc
from cellctl.classify.sample import label_from_mask
from cellctl.classify.texture import Look

__all__ = ["CANDIDATES", "label_check"]

CANDIDATES = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0)
"""Surroundings factors compared (a change of 0.5–3 times the local natural variation)."""


def label_check(
    surface: str, n_dirty: int, n_clean: int, seed: int, model: Path, candidates: tuple[float, ...] = CANDIDATES
) -> dict[str, Any]:
    """Figures per candidate factor (see the module doc)."""
    check_surface(surface)
    from cellctl.classify._twin_source import make_twin_source
    from cellctl.classify.fusion import Detector

    # the dataset's own stream layout, with a seed no data set uses
    rng = np.random.default_rng([seed, 1, 0 if surface == "external" else 1, 77])
    size = 256
    twin = make_twin_source(surface, size, False, seed, None)
    t0 = time.perf_counter()
    fixed_dirty: list[np.ndarray] = []  # twin-powder draws: their label does not depend on the factor
    layered: list[dict[str, Any]] = []
    for _ in range(n_dirty):
        keep: dict[str, Any] = {}
        d = _draw(True, surface, size, rng, twin, 0.4, 0.35, FAMILIES, Look(), False, clutter_k=0.0, keep=keep)
        if d is None:
            continue
        if keep:
            layered.append(keep)
        else:
            fixed_dirty.append(d[0])
    clean = [
        d[0]
        for d in (_draw(False, surface, size, rng, twin, 0.4, 0.35, FAMILIES, Look(), False) for _ in range(n_clean))
        if d
    ]
    det = Detector.load(model, surface=surface)
    p_clean = np.array([r.p_dirty for r in det.predict(clean)])
    p_fixed = np.array([r.p_dirty for r in det.predict(fixed_dirty)]) if fixed_dirty else np.zeros(0)
    p_layer = np.array([r.p_dirty for r in det.predict([k["dirty"] for k in layered])])
    rows = []
    for k in candidates:
        kept = []
        for i, dr in enumerate(layered):
            seen = visible_mask(dr["dirty"], dr["clean"], dr["alpha"], at_px=MODEL_INPUT_PX, clutter_k=k)
            lab = label_from_mask(seen, present=float((dr["alpha"] >= VISIBLE_ALPHA).mean()))
            if lab == "dirty":
                kept.append(i)
        p_dirty = np.r_[p_fixed, p_layer[kept]]
        thr = float(np.quantile(p_dirty, 0.01)) if len(p_dirty) else 1.0
        by_fam: dict[str, list[int]] = {}
        for i, dr in enumerate(layered):
            fam = dr["family"].split("+")[0]
            by_fam.setdefault(fam, [0, 0])[1] += 1
            if i in kept:
                by_fam[fam][0] += 1
        rows.append(
            {
                "clutter_k": k,
                "layered_kept": len(kept),
                "layered_drawn": len(layered),
                "kept_by_first_family": {f: f"{a}/{b}" for f, (a, b) in sorted(by_fam.items())},
                "dirty_n": int(len(p_dirty)),
                "roc_auc": roc_auc(np.r_[p_clean, p_dirty], np.r_[np.zeros(len(p_clean)), np.ones(len(p_dirty))]),
                "threshold_at_99pct_recall": round(thr, 5),
                "clean_specificity_at_99pct_recall": round(float((p_clean < thr).mean()), 4),
            }
        )
    return {
        "surface": surface,
        "seed": seed,
        "model": str(model),
        "model_id": det.model_id,
        "clean_n": len(p_clean),
        "twin_powder_n": len(p_fixed),
        "seconds": round(time.perf_counter() - t0, 1),
        "candidates": rows,
    }
