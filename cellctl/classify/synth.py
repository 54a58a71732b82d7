"""Synthetic labelled datasets: ``cellctl dataset synth``.

Sources:

* ``twin`` — the pybullet twin's camera (:mod:`cellctl.sim`) renders the bin (brushed steel
  outside, polished inside, seeded powder) at viewpoints around it (planned viewpoints when a
  plan exists, else sampled poses facing the surface) and returns the visible-powder mask.
* ``procedural`` — :mod:`cellctl.classify.texture` (steel + powder images with exact masks);
  used by the tests and when no renderer is available.

Label rule (both sources, :mod:`cellctl.classify.sample`): a pixel shows powder when its
powder opacity is ≥ 0.5 and (twin) the powder changes the pixel by at least
:data:`~cellctl.classify.sample.MIN_CONTRAST` grey levels against the same render without powder
(same light, same sensor noise), so powder washed out by glare or lost in the dark does not
count as visible. An image is **dirty** when at least
:data:`~cellctl.classify.sample.MIN_VISIBLE_FRACTION` of its pixels show powder, **clean** when
no powder lies in view at all. Images in between (a few visible powder pixels, or powder in view
but not visible) are discarded and drawn again, so every stored label is true by construction.

Half the draws are clean (no powder seeded) and half dirty (powder amount varied). Lighting,
exposure and camera noise are varied per image from a seeded RNG. ``shifted=True`` draws from
another distribution (warm light, yellowish powder, stronger noise, wider exposure range) to
measure generalisation. Every stored image is listed in ``<out>/<surface>/labels.csv`` with
its visible powder fraction and the parameters it was made with.
"""

from __future__ import annotations

import csv
import json
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from cellctl.classify.collect import LABELS, check_surface
from cellctl.classify.sample import MIN_VISIBLE_FRACTION, POWDER_ALPHA, Sample, label_from_mask
from cellctl.errors import ClassifierError

__all__ = ["synth_dataset"]


def _procedural_source(surface: str, size: int, shifted: bool) -> Callable[[np.random.Generator, bool], Sample]:
    from cellctl.classify.texture import Look, composite, powder_layer, steel_image

    look = Look.shifted() if shifted else Look()

    def draw(rng: np.random.Generator, dirty: bool) -> Sample:
        coverage = float(rng.uniform(0.004, 0.06)) if dirty else 0.0
        steel = steel_image(surface, size, rng, look)
        alpha = powder_layer(size, rng, coverage)
        return Sample(composite(steel, alpha, rng, look), alpha, {"coverage": round(coverage, 4)})

    return draw


def _twin_source(
    surface: str, size: int, shifted: bool, seed: int, config: Any
) -> Callable[[np.random.Generator, bool], Sample]:
    from cellctl.classify._twin_source import make_twin_source

    return make_twin_source(surface, size, shifted, seed, config)


def _draws(n: int, rng: np.random.Generator) -> Iterator[bool]:
    """Balanced clean/dirty intents in random order."""
    intents = np.r_[np.zeros(n - n // 2, bool), np.ones(n // 2, bool)]
    rng.shuffle(intents)
    yield from (bool(x) for x in intents)


def synth_dataset(
    out: Path | str,
    surface: str,
    n: int,
    *,
    seed: int = 0,
    shifted: bool = False,
    source: str = "twin",
    size: int = 256,
    config: Any = None,
    max_tries: int = 20,
) -> dict[str, Any]:
    """Generate ``n`` labelled images into ``out/<surface>/<clean|dirty>/``.

    Args:
        out: dataset root.
        surface: ``external`` or ``internal``.
        n: number of images to store (about half clean, half dirty).
        seed: RNG seed (same seed, same images).
        shifted: draw from the shifted distribution (see module doc).
        source: ``twin`` or ``procedural``.
        size: stored image width in px (twin: 16:9 renders ``size`` px wide; procedural:
            ``size``² images). The classifier input is 128 px.
        config: the cell config (twin source: bin type/catalog/plans).
        max_tries: redraws allowed per image before giving up (ambiguous labels).

    Returns:
        Summary: counts, discarded draws, seconds, output folder.

    Raises:
        ClassifierError: bad arguments, or the source keeps producing ambiguous images.
    """
    check_surface(surface)
    if n < 4:
        raise ClassifierError(f"n={n} is too small; expected at least 4 images (2 per class)")
    if not 32 <= size <= 2048:
        raise ClassifierError(f"image size {size} px must be in [32, 2048]")
    rng = np.random.default_rng([seed, int(shifted), 0 if surface == "external" else 1])
    if source == "procedural":
        draw = _procedural_source(surface, size, shifted)
    elif source == "twin":
        draw = _twin_source(surface, size, shifted, seed, config)
    else:
        raise ClassifierError(f"source {source!r} is unknown; expected 'twin' or 'procedural'")
    base = Path(out) / surface
    for lab in LABELS:
        (base / lab).mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    counts = {lab: 0 for lab in LABELS}
    discarded = 0
    rows = []
    tag = "shifted" if shifted else "synth"
    for i, dirty in enumerate(
        tqdm(
            list(_draws(n, rng)),
            desc=f"synth {surface} ({source}{', shifted' if shifted else ''})",
            file=sys.stderr,
        )
    ):
        for _ in range(max_tries):
            s = draw(rng, dirty)
            label = label_from_mask(s.powder, present=s.params.get("powder_in_view"))
            if label is not None:
                break
            discarded += 1
        else:
            raise ClassifierError(
                f"image {i}: {max_tries} draws in a row had an ambiguous powder area; check the source"
            )
        name = f"{tag}_{surface}_{seed}_{i:05d}.png"
        # Stored as rendered (twin: 16:9 at ``size`` px wide; procedural: size²); the
        # classifier squashes to its square input identically at training and inference.
        cv2.imwrite(str(base / label / name), cv2.cvtColor(s.rgb, cv2.COLOR_RGB2BGR))
        counts[label] += 1
        frac = float((s.powder >= POWDER_ALPHA).mean())
        rows.append(
            {
                "image": f"{label}/{name}",
                "label": label,
                "intended": LABELS[int(dirty)],
                "visible_fraction": round(frac, 5),
                "params": json.dumps(s.params, sort_keys=True),
            }
        )
    with open(base / "labels.csv", "a" if (base / "labels.csv").exists() else "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        if f.tell() == 0:
            w.writeheader()
        w.writerows(rows)
    summary = {
        "out": str(base),
        "surface": surface,
        "source": source,
        "shifted": shifted,
        "seed": seed,
        "size": size,
        "counts": counts,
        "discarded_ambiguous": discarded,
        "seconds": round(time.perf_counter() - t0, 1),
        "min_visible_fraction": MIN_VISIBLE_FRACTION,
    }
    # Provenance read by `cellctl train` into the model card (and by the bench to draw a
    # fresh test set from the same source). Appending runs keep a list.
    prov_path = base / "synth.json"
    runs = json.loads(prov_path.read_text()) if prov_path.is_file() else []
    prov_path.write_text(json.dumps([*runs, summary], indent=1) + "\n")
    return summary
