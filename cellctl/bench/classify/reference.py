"""``cellctl bench reference``: fit the reference decision on generated pairs, measure it, time it.

Stages (each a function; :func:`bench_reference` runs them in order, every draw seeded):

1. :func:`draw_pairs` — twin pairs (:mod:`cellctl.bench.classify.pairs`) at the demo's
   parking error, half dirty: training families for the **fit** (seed ``--seed``), the
   held-out families for the **measurement** (seed ``--seed + 1000``, never fitted on).
2. :func:`score_pairs` — per pair: the detector's maps and its own ``p_dirty``, the alignment,
   the change features, the patch labels.
3. :func:`fit_fusion` — change logistic on the aligned patches, the fused patch logistic
   ``z = w_s·s + w_a·a + w_c·c + g·(w_gs·s + w_ga·a) + b`` (class-balanced), Platt on the image max, the threshold
   for the false-clean target (1 %).
4. :func:`measure` — per-view accuracy, false-clean, false-dirty (Clopper–Pearson) with the
   reference and with the detector alone on the same held-out pairs; per family.
5. :func:`mirror_sweep` — clean internal pairs (arm and camera mirrored) at growing pose deltas:
   alignment rejections and false-dirty of the fused decision; the tolerance is the largest
   delta whose false-dirty stays within the zero-delta level plus the 95 % interval.
6. :func:`latency` — batch-1 time of the whole per-view decision with the reference
   (:func:`cellctl.classify.reference.decide`) beside the detector alone, interleaved.

``--n``: pairs per surface for the fit (default 240; the measurement draws 2/3 of it).
The fitted fusions are written beside ``--out`` (``<surface>.reference.json``); copy them to
``models/classifier/`` to ship them. A PNG of (reference, view, change heat, fused heat) triples
is written beside ``--out`` too.
"""

from __future__ import annotations

import os
import pickle
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cellctl.bench.classify.pairs import (
    BIN_POSE_ERROR,
    CYCLE_LIGHT_SCALE,
    DEMO_PARKING_ERROR,
    Pair,
    make_pair_source,
)
from cellctl.bench.options import BenchOptions
from cellctl.classify.reference import (
    MIRROR_POSE_TOLERANCE,
    Alignment,
    ReferenceFusion,
    ReferenceView,
    compare,
    decide,
    detector_maps,
    fusion_inputs,
    to_work,
)

__all__ = [
    "ScoredPair",
    "bench_reference",
    "clean_threshold",
    "draw_pairs",
    "fit_fusion",
    "latency",
    "measure",
    "mirror_sweep",
    "reference_surface",
    "score_pairs",
]

TARGET_FALSE_CLEAN = 0.01
MIRROR_LEVELS = (
    (0.0, 0.0),
    (2.5, 0.0),
    (5.0, 0.0),
    (7.5, 0.0),
    (10.0, 0.0),
    (15.0, 0.0),
    (20.0, 0.0),
    (40.0, 0.0),
    (0.0, 0.5),
    (0.0, 1.0),
    (0.0, 2.0),
    (0.0, 4.0),
)
"""(mm, deg) pose deltas of the mirror sweep: translations alone, then rotations alone."""

PLATT_L2 = 1e-2
"""L2 pull of the Platt slope (:func:`fit_fusion`)."""

@dataclass
class ScoredPair:
    """What the fit and the measurement need of one pair."""

    label: int
    family: str
    s: NDArray[np.float32] = field(repr=False)
    a: NDArray[np.float32] = field(repr=False)
    p_det: float
    alignment: Alignment = field(repr=False)
    feats: NDArray[np.float32] | None = field(repr=False)
    patch: NDArray[np.float32] = field(repr=False)


def draw_pairs(
    draw: Any,
    n: int,
    seed: int,
    held_out: bool,
    delta: tuple[float, float] = DEMO_PARKING_ERROR,
    dirty_share: float = 0.5,
) -> list[Pair]:
    """``n`` pairs, ``dirty_share`` of them dirty, redrawing ambiguous ones (seeded)."""
    rng = np.random.default_rng([seed, 4242, int(held_out)])
    out: list[Pair] = []
    k = 0
    while len(out) < n:
        dirty = len(out) < int(round(n * dirty_share))
        p = draw(rng, dirty, held_out, delta)
        k += 1
        if p is not None:
            out.append(p)
        if k > 40 * n:
            from cellctl.errors import ClassifierError

            raise ClassifierError(f"{k} draws gave only {len(out)} of {n} pairs; check the pair source")
    return out


def _patch_labels(mask: NDArray[np.float32], grid: int) -> NDArray[np.float32]:
    import cv2

    return cv2.resize(mask.astype(np.float32), (grid, grid), interpolation=cv2.INTER_AREA)


def score_pairs(det: Any, pairs: list[Pair]) -> list[ScoredPair]:
    """The detector's maps, the alignment and the change features of each pair."""
    out = []
    for p in pairs:
        nw = to_work(p.new)
        s, a, sc = detector_maps(det, nw)
        al, feats = compare(ReferenceView(p.ref, p.T_ref, p.plane, p.K), nw, p.T_new, p.new.shape[1], p.new.shape[0])
        out.append(
            ScoredPair(p.label, p.info["family"], s, a, float(sc["p"][0]), al, feats, _patch_labels(p.mask, s.shape[0]))
        )
    return out


def fit_fusion(det: Any, scored: list[ScoredPair], surface: str, card: dict[str, Any]) -> ReferenceFusion:
    """Fit the change logistic, the fused patch logistic, Platt and the threshold on ``scored``."""
    from cellctl.classify.evaluate import choose_threshold
    from cellctl.classify.finetune import PATCH_DIRTY
    from cellctl.classify.fusion import _fit_logistic

    used = [sp for sp in scored if sp.feats is not None]
    F = np.concatenate([sp.feats.reshape(3, -1).T for sp in used])
    S = np.concatenate([sp.s.ravel() for sp in used])
    A = np.concatenate([sp.a.ravel() for sp in used])
    M = np.concatenate([sp.patch.ravel() for sp in used])
    keep = (M >= PATCH_DIRTY) | (M == 0)
    y = (M >= PATCH_DIRTY)[keep].astype(np.float64)
    wts = np.where(y > 0, (len(y) - y.sum()) / max(y.sum(), 1.0), 1.0)
    change = _fit_logistic(F[keep], y, wts)
    C = F @ change[:3] + change[3]
    fuse = _fit_logistic(fusion_inputs(S, A, C).T[keep], y, wts)

    def zmax(sp: ScoredPair) -> float:
        c = np.tensordot(change[:3], sp.feats, 1) + change[3]
        return float((np.tensordot(fuse[:5], fusion_inputs(sp.s, sp.a, c), 1) + fuse[5]).max())

    zmax_all = np.array([zmax(sp) for sp in used])
    yl = np.array([sp.label for sp in used], np.float64)
    # a small pull on the slope: pairs drawn as cycles separate almost perfectly at image level, and an
    # unpenalised slope then runs off (208 at 150 external pairs, seed 30), a step that leaves no view
    # uncertain; the pull keeps the calibration a slope of a few per logit
    platt = _fit_logistic(zmax_all[:, None], yl, l2=PLATT_L2)
    p = 1.0 / (1.0 + np.exp(-(platt[0] * zmax_all + platt[1])))
    thr = choose_threshold(p, yl, TARGET_FALSE_CLEAN)
    return ReferenceFusion(
        surface,
        tuple(float(v) for v in change),
        tuple(float(v) for v in fuse),
        (float(platt[0]), float(platt[1])),
        float(thr),
        float(det.band),
        {
            **card,
            "n_pairs": len(scored),
            "n_aligned": len(used),
            "n_patches": int(keep.sum()),
            "model_id": det.model_id,
        },
    )


def clean_threshold(
    fusion: ReferenceFusion, fit: list[ScoredPair], clean: list[ScoredPair], seed: int
) -> ReferenceFusion:
    """The fusion with its threshold raised, where needed, above every held-out clean pair's score.

    The fit's threshold holds its false-clean target on the fit pairs but says nothing of clean views
    it never saw. ``clean`` are held-out clean pairs (their own seed, drawn as a cycle draws them):
    the threshold is set so that none of them is called dirty — zero of n, whose 95 % upper limit
    (``rate``) the card keeps — half-way in logit space between the highest clean score and the
    lowest fit-dirty score above it. It never goes past 0.5 (``choose_threshold``'s cap: a threshold
    is not raised past even odds to buy fewer false alarms) nor below the fit's.
    """
    from dataclasses import replace

    from cellctl.classify.proof import rate

    def logit(p: float) -> float:
        p = min(max(p, 1e-9), 1 - 1e-9)
        return float(np.log(p / (1 - p)))

    pc = np.array([_p_ref(fusion, sp)[0] for sp in clean if sp.feats is not None])
    pd = np.array([_p_ref(fusion, sp)[0] for sp in fit if sp.feats is not None and sp.label == 1])
    thr = fusion.threshold
    if len(pc) and pc.max() >= thr:
        c = float(pc.max())
        above = pd[pd > c]
        t = 1.0 / (1.0 + np.exp(-(logit(c) + logit(float(above.min()))) / 2.0)) if len(above) else c + 1e-6
        thr = float(min(max(t, thr), 0.5))
    fd = int((pc >= thr).sum())
    card = {
        **fusion.card,
        "threshold_rule": "max(fit false-clean target, above every held-out clean pair), capped at 0.5",
        "threshold_fit": fusion.threshold,
        "threshold_clean_pairs": {"seed": seed, "aligned": int(len(pc)), "false_dirty": rate(fd, int(len(pc)))},
        "threshold_fit_false_clean": rate(int((pd < thr).sum()), int(len(pd))),
    }
    return replace(fusion, threshold=thr, card=card)


def _p_ref(fusion: ReferenceFusion, sp: ScoredPair) -> tuple[float, float]:
    """(p_dirty, threshold) of the deciding path for a scored pair."""
    if sp.feats is None:
        return sp.p_det, float("nan")
    z = fusion.patch_logit(sp.s, sp.a, fusion.change_logit(sp.feats))
    return fusion.p_image(z), fusion.threshold


def measure(det: Any, fusion: ReferenceFusion, scored: list[ScoredPair]) -> dict[str, Any]:
    """Figures with the reference and with the detector alone on the same pairs."""
    from cellctl.classify.proof import rate, rate_figures

    y = np.array([sp.label for sp in scored])
    p_det = np.array([sp.p_det for sp in scored])
    from cellctl.classify.evaluate import roc_auc

    dec_ref = []
    p_ref = []
    for sp in scored:
        p, t = _p_ref(fusion, sp)
        dec_ref.append(p >= (t if sp.feats is not None else det.threshold))
        p_ref.append(p)
    pred = np.array(dec_ref, int)
    auc = roc_auc(np.array(p_ref), y)
    fams: dict[str, dict[str, int]] = {}
    for sp, d, pd in zip(scored, pred, p_det >= det.threshold, strict=True):
        e = fams.setdefault(sp.family, {"n": 0, "wrong_reference": 0, "wrong_detector": 0})
        e["n"] += 1
        e["wrong_reference"] += int(d != sp.label)
        e["wrong_detector"] += int(int(pd) != sp.label)
    reasons: dict[str, int] = {}
    for sp in scored:
        reasons[sp.alignment.reason] = reasons.get(sp.alignment.reason, 0) + 1
    return {
        "n": len(y),
        "with_reference": {
            "accuracy": rate(int((pred == y).sum()), len(y)),
            "false_clean": rate(int(((pred == 0) & (y == 1)).sum()), int((y == 1).sum())),
            "false_dirty": rate(int(((pred == 1) & (y == 0)).sum()), int((y == 0).sum())),
            "roc_auc": None if auc is None else round(auc, 5),
            "threshold": round(fusion.threshold, 6),
        },
        "detector_alone": rate_figures(p_det, y, det.threshold),
        "alignment": reasons,
        "by_family": fams,
    }


def mirror_sweep(det: Any, fusion: ReferenceFusion, draw: Any, n: int, seed: int) -> dict[str, Any]:
    """Clean internal pairs at each of :data:`MIRROR_LEVELS` (arm and camera mirrored): alignment
    rejections, the **false-change rate** (share of pairs with any patch's change probability
    ``sigmoid(c)`` ≥ 0.5) and the fused decision's false-dirty. The tolerance: the largest delta
    (translation alone, rotation alone) whose false-change rate stays within the zero delta's
    95 % upper limit, with ≤ 10 % rejections."""
    from cellctl.classify.proof import rate

    rows = []
    for mm, deg in MIRROR_LEVELS:
        print(f"bench reference: mirror sweep {mm} mm {deg} deg", file=sys.stderr)
        sc = score_pairs(det, draw_pairs(draw, n, seed, False, (mm, deg), dirty_share=0.0))
        ok = [sp for sp in sc if sp.feats is not None]
        cmax = np.array([float(fusion.change_logit(sp.feats).max()) for sp in ok])
        fd = sum(
            int(_p_ref(fusion, sp)[0] >= (fusion.threshold if sp.feats is not None else det.threshold)) for sp in sc
        )
        rows.append(
            {
                "translation_mm": mm,
                "rotation_deg": deg,
                "false_change": rate(int((cmax >= 0).sum()), len(ok)) if ok else rate(0, 0),
                "change_logit_max_quartiles": [round(float(v), 3) for v in np.percentile(cmax, [25, 50, 75])]
                if ok
                else None,
                "rejected": rate(len(sc) - len(ok), len(sc)),
                "false_dirty": rate(fd, len(sc)),
                "detector_false_dirty": rate(int(sum(sp.p_det >= det.threshold for sp in sc)), len(sc)),
            }
        )
    bound = rows[0]["false_change"]["ci95"][1]

    def within(r: dict[str, Any]) -> bool:
        return r["false_change"]["rate"] <= bound and r["rejected"]["rate"] <= 0.1

    ok_t = [r["translation_mm"] for r in rows if r["rotation_deg"] == 0 and within(r)]
    ok_r = [r["rotation_deg"] for r in rows if r["translation_mm"] == 0 and within(r)]
    return {
        "levels": rows,
        "n_per_level": n,
        "seed": seed,
        "rule": "largest delta (alone) whose false-change rate stays <= the zero-delta 95 % upper limit "
        "and whose rejections <= 10 %",
        "tolerance_measured": {"translation_mm": max(ok_t, default=0.0), "rotation_deg": max(ok_r, default=0.0)},
        "tolerance_shipped": {
            "translation_mm": MIRROR_POSE_TOLERANCE.translation_mm,
            "rotation_deg": MIRROR_POSE_TOLERANCE.rotation_deg,
        },
    }


def latency(det: Any, fusion: ReferenceFusion, pairs: list[Pair], n: int) -> dict[str, Any]:
    """Batch-1 ms of :func:`decide` with the reference beside the detector alone (interleaved).

    OpenCV runs on one thread here, as ONNX Runtime does on 2 cores (``runtime.default_threads``):
    at 128 px its thread hand-offs cost more than they save, and under load far more (ECC median
    17 → 11 ms, change features 14 → 12 ms at load 30, measured)."""
    import cv2

    cv2.setNumThreads(1)
    refs = [ReferenceView(p.ref, p.T_ref, p.plane, p.K) for p in pairs]
    fns = {
        "detector_alone": lambda i: decide(det, None, pairs[i].new, pairs[i].T_new, None),
        "with_reference": lambda i: decide(det, fusion, pairs[i].new, pairs[i].T_new, refs[i]),
    }
    for fn in fns.values():
        for i in range(min(5, len(pairs))):
            fn(i)
    ts: dict[str, list[float]] = {k: [] for k in fns}
    load0 = os.getloadavg()
    for i in range(n):
        for k, fn in fns.items():
            t = time.perf_counter()
            fn(i % len(pairs))
            ts[k].append((time.perf_counter() - t) * 1000)
    load1 = os.getloadavg()
    out: dict[str, Any] = {
        k: {
            "ms_p50": round(float(np.percentile(v, 50)), 2),
            "ms_p95": round(float(np.percentile(v, 95)), 2),
            "ms_min": round(float(np.min(v)), 2),
        }
        for k, v in ts.items()
    }
    out["loadavg"] = {"start": [round(v, 2) for v in load0], "end": [round(v, 2) for v in load1]}
    out["n"] = n
    out["note"] = (
        "whole per-view decision from an RGB frame: squash, detector (ONNX Runtime), pose prior, ECC, warp, "
        "change features, fusion"
    )
    return out


def _heat_rgb(x: NDArray[np.float32], shape: tuple[int, ...]) -> NDArray[np.uint8]:
    """A (G, G) probability map as an inferno RGB image of ``shape``'s size."""
    import cv2

    q = np.clip(x * 255, 0, 255).astype(np.uint8)
    big = cv2.resize(q, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    return cv2.cvtColor(cv2.applyColorMap(big, cv2.COLORMAP_INFERNO), cv2.COLOR_BGR2RGB)


def figure(det: Any, fusion: ReferenceFusion, pairs: list[Pair], path: Path) -> None:
    """(reference, view, change heat, fused heat) rows of ``pairs``, written as a PNG."""
    import cv2

    rows = []
    for p in pairs:
        d = decide(det, fusion, p.new, p.T_new, ReferenceView(p.ref, p.T_ref, p.plane, p.K))

        new = p.new.copy()
        if p.mask.any():
            cnt, _ = cv2.findContours((p.mask > 0).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            cv2.drawContours(new, cnt, -1, (0, 255, 0), 1)
        row = np.hstack([p.ref, new, _heat_rgb(d.change_heat, new.shape), _heat_rgb(d.heat, new.shape)])
        txt = f"{p.info['family']} p={d.p_dirty:.2f} det={d.detector_p:.2f} {d.path}/{d.reason}"
        cv2.putText(row, txt, (4, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (255, 255, 0), 1, cv2.LINE_AA)
        rows.append(row)
    cv2.imwrite(str(path), cv2.cvtColor(np.vstack(rows), cv2.COLOR_RGB2BGR))


def reference_surface(cfg: Any, surface: str, n: int, seed: int, outdir: Path) -> dict[str, Any]:
    """Every stage for one surface: fit on ``n`` pairs, measure on ``2n/3`` held-out ones, the
    mirror sweep (internal), latency and the figure; the fusion and the PNG go to ``outdir``."""
    from cellctl.classify.fusion import Detector, detector_path

    det = Detector.load(detector_path(cfg.path(cfg.classifier.models_dir), surface), surface=surface, threads=1)
    draw = make_pair_source(surface, cfg)
    t0 = time.perf_counter()
    print(f"bench reference: {surface}: drawing {n} fit pairs (training families)", file=sys.stderr)
    fit_sc = score_pairs(det, draw_pairs(draw, n, seed, False))
    card = {
        "command": f"cellctl bench reference --n {n} --seed {seed}",
        "fit_seed": seed,
        "delta": list(DEMO_PARKING_ERROR),
        "pairs": "as a commissioned cycle: bin parked off by delta (mm, deg yaw) at commissioning and at the "
        f"cycle under the cabin's fixed lights, camera at the plan in a measured bin frame off by <= "
        f"{list(BIN_POSE_ERROR)} mm/deg, light level and exposure U{list(CYCLE_LIGHT_SCALE)} per view",
        "families": "training (contamination.FAMILIES) + twin powder",
    }
    fusion = fit_fusion(det, fit_sc, surface, card)
    n_cal = max(n // 2, 20)
    print(f"bench reference: {surface}: drawing {n_cal} held-out clean pairs (threshold)", file=sys.stderr)
    cal_sc = score_pairs(det, draw_pairs(draw, n_cal, seed + 3000, True, dirty_share=0.0))
    fusion = clean_threshold(fusion, fit_sc, cal_sc, seed + 3000)
    outdir.mkdir(parents=True, exist_ok=True)
    fusion.save(outdir / f"{surface}.reference.json")
    print(f"bench reference: {surface}: drawing {(2 * n) // 3} held-out pairs", file=sys.stderr)
    meas_pairs = draw_pairs(draw, (2 * n) // 3, seed + 1000, True)
    held_sc = score_pairs(det, meas_pairs)
    res: dict[str, Any] = {
        "n_fit": n,
        "n_measure": len(meas_pairs),
        "fusion": {"change": fusion.change, "fuse": fusion.fuse, "platt": fusion.platt, "threshold": fusion.threshold},
        "fit_in_sample": measure(det, fusion, fit_sc),
        "held_out": measure(det, fusion, held_sc),
        "held_out_note": f"held-out families (shifted.HELD_OUT_FAMILIES) + twin powder, seed {seed + 1000}",
    }
    with open(outdir / f"{surface}_scored.pkl", "wb") as f:
        # the scored pairs, so a change of the fusion's form is refitted without re-rendering
        pickle.dump({"fit": fit_sc, "held_out": held_sc}, f)
    res["latency"] = latency(det, fusion, meas_pairs, min(100, 2 * len(meas_pairs)))
    if surface == "internal":
        # the sweep moves the camera alone by each delta (the first fit's pairs): what mirrored content tolerates
        res["mirror"] = mirror_sweep(
            det, fusion, make_pair_source(surface, cfg, cycle=False), max(12, n // 10), seed + 2000
        )
    pick = [p for p in meas_pairs if p.label][:3] + [p for p in meas_pairs if not p.label][:1]
    figure(det, fusion, pick, outdir / f"triples_{surface}.png")
    res["seconds"] = round(time.perf_counter() - t0, 1)
    return res


def bench_reference(opts: BenchOptions) -> dict[str, Any]:
    """Fit and measure the reference decision per surface (see the module doc)."""
    import torch

    from cellctl.surface import SURFACES

    cfg = opts.load_config()
    torch.set_num_threads(1)
    n = opts.n or 240
    outdir = (opts.out.parent if opts.out else Path("logs")) / "reference"
    result: dict[str, Any] = {"seed": opts.seed}
    for surface in SURFACES:
        result[surface] = reference_surface(cfg, surface, n, opts.seed, outdir)
    result["setup"] = {"cpu_count": os.cpu_count(), "loadavg_end": [round(v, 2) for v in os.getloadavg()], "threads": 1}
    return result
