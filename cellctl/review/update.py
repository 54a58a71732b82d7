"""``cellctl detector update``: re-enroll a surface's detector from the views operators confirmed clean.

The bank's confirmed-clean views of the surface (:mod:`cellctl.review.bank`, hashes checked) are
enrolled (:func:`cellctl.classify.enroll.enroll_detector`) on the *shipped* detector, like a
commissioning enrollment: re-enrolling an enrolled file would stack one site bank on another, and
the shipped file is the one whose false-clean figure was proven. The result is one file (``--out``)
for ``classifier.detector_files.<surface>``; nothing in the config is changed.

How the decision moved, before (the detector the cell uses now: ``detector_files.<surface>`` or
the shipped one) and after:

* the threshold;
* false-dirty on the accumulated confirmed-clean views (optimistic after: half of them are in the
  new bank; the enrollment's own held-out figure is in ``card``) and detection of the
  confirmed-dirty views (labelled examples the enrollment never uses);
* false-dirty and false-clean on a small generated held-out set of the unseen site
  (:func:`cellctl.classify.site.site_dataset`, its own seed: none of these images is in the bank);
* optionally the shifted section of ``cellctl detector proof --quick`` on both files.
"""

from __future__ import annotations

import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cellctl.config import CellConfig
from cellctl.errors import ClassifierError, RecordingError
from cellctl.review.bank import bank_dir, open_bank

__all__ = ["HELD_OUT_SEED", "update_detector"]

HELD_OUT_SEED = 701
"""Offset of the generated held-out set's seed (the proof's sets use 101..501)."""


def _say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _rates(det: Any, paths: list[Path], dirty: bool, max_pixels: int) -> dict[str, Any]:
    """How many of ``paths`` ``det`` calls dirty (the false-dirty count of clean views, the hits of dirty ones)."""
    from cellctl.classify.data import load_image

    if not paths:
        return {"n": 0, "called_dirty": 0, "rate": None}
    preds = det.predict([load_image(p, max_pixels) for p in paths])
    k = sum(p.label == "dirty" for p in preds)
    key = "false_clean" if dirty else "false_dirty"
    return {"n": len(paths), "called_dirty": k, key: round((len(paths) - k if dirty else k) / len(paths), 4)}


def update_detector(
    cfg: CellConfig,
    surface: str,
    out: Path,
    *,
    base: Path | None = None,
    seed: int = 0,
    held_out: int = 12,
    proof_quick: bool = False,
    progress: Callable[[str], None] | None = _say,
) -> dict[str, Any]:
    """Re-enroll ``surface`` from the review bank's clean views and report the move (module doc).

    Args:
        base: the detector to enroll on (default the shipped ``<models_dir>/<surface>.detect.pt``).
        held_out: clean and dirty images of the generated held-out set (each).
        proof_quick: also run the shifted section of ``detector proof --quick`` on both files.

    Raises:
        ClassifierError: fewer confirmed-clean views than enrollment needs, a bad detector, or an
            enrollment refusal. RecordingError: the bank is damaged (a file changed since review).
    """
    from cellctl.classify.enroll import MIN_IMAGES, enroll_detector, save_enrolled
    from cellctl.classify.fusion import Detector, detector_path

    say = progress or (lambda _m: None)
    bank = open_bank(cfg)
    try:
        clean, dirty = bank.files(surface, "clean"), bank.files(surface, "dirty")
    except RecordingError as err:
        raise ClassifierError(f"review bank {str(bank.root)!r}: {err}") from err
    if len(clean) < MIN_IMAGES:
        raise ClassifierError(
            f"the review bank holds {len(clean)} confirmed-clean {surface} view(s) in {str(bank.root)!r}; "
            f"re-enrollment needs at least {MIN_IMAGES} (confirm more views clean on the HMI's Review page)"
        )
    shipped = base or detector_path(cfg.path(cfg.classifier.models_dir), surface)
    current_file = getattr(cfg.classifier.detector_files, surface)
    now_path = cfg.path(current_file) if current_file is not None else shipped
    before = Detector.load(now_path, surface=surface)
    say(f"detector update {surface}: {len(clean)} confirmed-clean views, {len(dirty)} confirmed-dirty")
    after = enroll_detector(
        Detector.load(shipped, surface=surface) if now_path != shipped else before,
        clean, surface, seed=seed, source=bank_dir(cfg) / surface / "clean", progress=progress,
    )  # fmt: skip
    save_enrolled(after, out)
    mp = cfg.camera.max_image_pixels
    report: dict[str, Any] = {
        "surface": surface,
        "out": str(out),
        "before": {"model_id": before.model_id, "path": str(now_path), "threshold": round(before.threshold, 6)},
        "after": {"model_id": after.model_id, "threshold": round(after.threshold, 6)},
        "bank": {"clean": len(clean), "dirty": len(dirty), "root": str(bank.root)},
        "card": (after.enrollment or {}).get("held_out"),
    }
    for name, det in (("before", before), ("after", after)):
        report[name]["bank_clean"] = _rates(det, clean, False, mp)
        report[name]["bank_dirty"] = _rates(det, dirty, True, mp)
    with tempfile.TemporaryDirectory(prefix="cellctl-update-") as tmp:
        from cellctl.classify.site import site_dataset

        say(f"detector update {surface}: generating a held-out set ({held_out} clean + {held_out} dirty)")
        site_dataset(Path(tmp) / "held_out", surface, held_out, held_out, seed=seed + HELD_OUT_SEED)
        root = Path(tmp) / "held_out" / surface
        hc, hd = sorted((root / "clean").glob("*.png")), sorted((root / "dirty").glob("*.png"))
        report["held_out"] = {"generator": "unseen site", "seed": seed + HELD_OUT_SEED}
        for name, det in (("before", before), ("after", after)):
            report[name]["held_out_clean"] = _rates(det, hc, False, mp)
            report[name]["held_out_dirty"] = _rates(det, hd, True, mp)
    if proof_quick:
        from cellctl.classify.proof import ProofSizes, proof

        for name, path in (("before", now_path), ("after", out)):
            say(f"detector update {surface}: detector proof --quick (shifted) {name}")
            p = proof(surface, path, sizes=ProofSizes.quick(), seed=seed, sections=("shifted",), progress=progress)
            report[name]["proof_quick_shifted"] = p["shifted"]["figures"]
    return report
