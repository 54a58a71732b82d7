"""``cellctl dataset contam``: labelled clean/dirty sets spanning contamination families.

Every image starts from a clean base — a twin render (``source="mixed"``: a share
``twin_fraction`` of the draws; the twin's own camera at a sampled or planned viewpoint, see
:mod:`cellctl.classify._twin_source`) or a close-up steel texture
(:func:`~cellctl.classify.contamination.closeup_steel`: brushed external, polished internal
with reflections). A *dirty* draw then either keeps the twin's own powder render (a share
``twin_powder`` of dirty twin draws, labelled by the twin's visible-powder rule) or lays one or
two contamination layers (:mod:`cellctl.classify.contamination`) on the inspected surface's
pixels. Optics are drawn once per image and applied to its clean and dirty version alike, and
the label comes from the visible mask at the classifier's input size
(:func:`~cellctl.classify.contamination.visible_mask`, then
:func:`~cellctl.classify.sample.label_from_mask`); ambiguous draws are redrawn. The stored mask
is that visibility brought back to full size (the detector's patch labels).

``shifted=True`` is the held-out generator (:mod:`cellctl.classify.shifted`): its families,
optics and lighting are never drawn for training.

Layout: ``OUT/<surface>/<clean|dirty>/<name>.png`` (what ``cellctl train`` reads),
``OUT/<surface>/masks/<name>.png`` (visible mask 0/255, dirty images only: the patch labels of
the detector) and ``labels.csv`` (family, base, parameters), ``synth.json`` (provenance with
the seed).
"""

from __future__ import annotations

import csv
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from cellctl.classify.collect import LABELS, check_surface
from cellctl.classify.contamination import (
    CLUTTER_K,
    FAMILIES,
    MODEL_INPUT_PX,
    VISIBLE_ALPHA,
    Optics,
    closeup_steel,
    composite,
    draw_family,
    optics,
    visible_mask,
)
from cellctl.classify.sample import label_from_mask
from cellctl.classify.shifted import HELD_OUT_FAMILIES, ShiftedOptics
from cellctl.classify.texture import Look
from cellctl.errors import ClassifierError

__all__ = ["GENERATOR", "append_provenance", "contam_dataset", "write_draws"]

GENERATOR = "cellctl-contam/3"
"""Version of this generator, recorded in ``synth.json`` and the model cards (2: the visible mask
also judges a change against its surroundings in the same image, :data:`~cellctl.classify.contamination.CLUTTER_K`;
3: two more training families, ``soot`` and ``tarnish``: dark matte smudges and darker-than-steel films)."""


def contam_dataset(
    out: Path | str,
    surface: str,
    n: int,
    *,
    seed: int = 0,
    shifted: bool = False,
    source: str = "mixed",
    twin_fraction: float = 0.4,
    twin_powder: float = 0.35,
    size: int = 256,
    config: Any = None,
    max_tries: int = 20,
) -> dict[str, Any]:
    """Generate ``n`` labelled images (half clean, half dirty) into ``out/<surface>/``.

    Args:
        source: ``mixed`` (twin renders + close-ups) or ``closeup`` (no renderer; tests).
        twin_fraction: share of draws on a twin render (``mixed`` only).
        twin_powder: share of dirty twin draws that keep the twin's own powder.
        size: close-up side and twin render width in px.

    Raises:
        ClassifierError: bad arguments, or a source that keeps giving ambiguous draws.
    """
    check_surface(surface)
    if n < 4:
        raise ClassifierError(f"n={n} is too small; expected at least 4 images (2 per class)")
    if source not in ("mixed", "closeup"):
        raise ClassifierError(f"source {source!r} is unknown; expected 'mixed' or 'closeup'")
    if not 0.0 <= twin_fraction <= 1.0 or not 0.0 <= twin_powder <= 1.0:
        raise ClassifierError(f"twin_fraction {twin_fraction} and twin_powder {twin_powder} must be in [0, 1]")
    rng = np.random.default_rng([seed, 1 + int(shifted), 0 if surface == "external" else 1, 77])
    twin = None
    if source == "mixed" and twin_fraction > 0:
        from cellctl.classify._twin_source import make_twin_source

        twin = make_twin_source(surface, size, shifted, seed, config)
    families = HELD_OUT_FAMILIES if shifted else FAMILIES
    look = Look.shifted() if shifted else Look()
    base_dir = Path(out) / surface
    for sub in (*LABELS, "masks"):
        (base_dir / sub).mkdir(parents=True, exist_ok=True)
    tag = "shifted" if shifted else "contam"
    intents = np.r_[np.zeros(n - n // 2, bool), np.ones(n // 2, bool)]
    rng.shuffle(intents)
    t0 = time.perf_counter()

    def draw(dirty: bool) -> tuple[np.ndarray, np.ndarray, str, dict[str, Any]] | None:
        return _draw(dirty, surface, size, rng, twin, twin_fraction, twin_powder, families, look, shifted)

    desc = f"contam {surface}{' shifted' if shifted else ''}"
    drawn = write_draws(base_dir, f"{tag}_{surface}_{seed}", intents, draw, max_tries, desc)
    summary = {
        "generator": GENERATOR,
        "out": str(base_dir),
        "surface": surface,
        "source": source,
        "shifted": shifted,
        "seed": seed,
        "size": size,
        "n": n,
        "twin_fraction": twin_fraction if twin is not None else 0.0,
        "twin_powder": twin_powder,
        "families": sorted(families) + (["twin_powder"] if twin is not None and twin_powder > 0 else []),
        **drawn,
        "seconds": round(time.perf_counter() - t0, 1),
    }
    append_provenance(base_dir, summary)
    return summary


def write_draws(
    base_dir: Path,
    stem: str,
    intents: np.ndarray,
    draw: Callable[[bool], tuple[np.ndarray, np.ndarray, str, dict[str, Any]] | None],
    max_tries: int,
    desc: str,
) -> dict[str, Any]:
    """Draw one image per intent (True = dirty) into ``base_dir/<label>/<stem>_<i>.png`` (+ mask
    for dirty images), redrawing ambiguous draws, and append their rows to ``labels.csv``.

    ``draw(dirty)`` returns ``(rgb, visible mask, label, info)`` or None (ambiguous); ``info``
    names ``family`` and ``base`` and may carry ``params``. Returns ``counts`` per label,
    ``by_family`` and ``discarded_ambiguous`` (draws redrawn), as the provenance records them.

    Raises:
        ClassifierError: ``max_tries`` ambiguous draws in a row.
    """
    counts = {lab: 0 for lab in LABELS}
    by_family: dict[str, int] = {}
    discarded = 0
    rows = []
    for i, dirty in enumerate(tqdm(intents, desc=desc, file=sys.stderr)):
        for _ in range(max_tries):
            d = draw(bool(dirty))
            if d is not None:
                break
            discarded += 1
        else:
            raise ClassifierError(f"image {i}: {max_tries} draws in a row were ambiguous; check the generator")
        rgb, mask, label, info = d
        name = f"{stem}_{i:05d}.png"
        cv2.imwrite(str(base_dir / label / name), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        if label == "dirty":
            cv2.imwrite(str(base_dir / "masks" / name), (mask > 0.5).astype(np.uint8) * 255)
        counts[label] += 1
        fam = info["family"]
        by_family[fam] = by_family.get(fam, 0) + 1
        rows.append(
            {
                "image": f"{label}/{name}",
                "label": label,
                "family": fam,
                "base": info["base"],
                "visible_fraction": round(float((mask > 0.5).mean()), 5),
                "params": json.dumps(info.get("params", {}), sort_keys=True, default=str),
            }
        )
    csv_path = base_dir / "labels.csv"
    with open(csv_path, "a" if csv_path.exists() else "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        if f.tell() == 0:
            w.writeheader()
        w.writerows(rows)
    return {"counts": counts, "by_family": by_family, "discarded_ambiguous": discarded}


def append_provenance(base_dir: Path, summary: dict[str, Any]) -> None:
    """Append one generator run's summary to ``base_dir/synth.json`` (a list of runs)."""
    prov = base_dir / "synth.json"
    runs = json.loads(prov.read_text()) if prov.is_file() else []
    prov.write_text(json.dumps([*runs, summary], indent=1) + "\n")


def _draw(
    dirty: bool,
    surface: str,
    size: int,
    rng: np.random.Generator,
    twin: Any,
    twin_fraction: float,
    twin_powder: float,
    families: dict,
    look: Look,
    shifted: bool,
    clutter_k: float = CLUTTER_K,
    keep: dict[str, Any] | None = None,
) -> tuple[np.ndarray, np.ndarray, str, dict[str, Any]] | None:
    """One labelled image ``(rgb, visible mask, label, info)``, or None when ambiguous.

    ``keep``: a layered dirty draw's ``dirty``, ``clean`` and ``alpha`` are stored in it (the label
    check relabels the same draw under other rules, :mod:`cellctl.classify.label_check`).
    """
    opt = ShiftedOptics.draw(rng) if shifted else Optics.draw(rng)

    def camera(img: np.ndarray) -> np.ndarray:
        return opt.apply(img) if shifted else optics(img, opt)  # type: ignore[union-attr,arg-type]

    on_twin = twin is not None and rng.random() < twin_fraction
    if on_twin and dirty and rng.random() < twin_powder:
        s = twin(rng, True)
        # the twin's visible-powder rule already labelled it; optics change what is visible
        # only a little and are applied to the render as the camera would
        label = label_from_mask(s.powder, present=s.params.get("powder_in_view"))
        if label != "dirty":
            return None
        return camera(s.rgb.astype(np.float32) / 255.0), s.powder, "dirty", {"family": "twin_powder", "base": "twin"}
    if on_twin:
        s = twin(rng, False)
        base = s.rgb.astype(np.float32) / 255.0
        where = s.surface
        base_name = "twin"
    else:
        h = size if surface == "internal" or rng.random() < 0.5 else int(size * 9 / 16)
        base = closeup_steel(surface, h, size, rng, look)
        where = None
        base_name = "closeup"
    clean_img = camera(base)
    if not dirty:
        return clean_img, np.zeros(base.shape[:2], np.float32), "clean", {"family": "none", "base": base_name}
    names = list(families)
    picks = [names[int(rng.integers(len(names)))] for _ in range(1 + int(rng.random() < 0.2))]
    img, alpha = base, np.zeros(base.shape[:2], np.float32)
    params = {}
    for name in picks:
        layer = draw_family(name, base.shape[0], base.shape[1], rng, families)
        img, a = composite(img, layer, where)
        alpha = np.maximum(alpha, a)
        params[name] = layer.params
    dirty_img = camera(img)
    if keep is not None:
        keep.update(dirty=dirty_img, clean=clean_img, alpha=alpha, family="+".join(picks), base=base_name)
    seen = visible_mask(dirty_img, clean_img, alpha, at_px=MODEL_INPUT_PX, clutter_k=clutter_k)
    label = label_from_mask(seen, present=float((alpha >= VISIBLE_ALPHA).mean()))
    if label != "dirty":
        return None
    # the stored mask (the detector's patch labels) is the low-pass visibility, at full size
    h, w = dirty_img.shape[:2]
    vis = (cv2.resize(seen, (w, h), interpolation=cv2.INTER_NEAREST) > 0) & (alpha >= VISIBLE_ALPHA)
    return dirty_img, vis.astype(np.float32), "dirty", {"family": "+".join(picks), "base": base_name, "params": params}
