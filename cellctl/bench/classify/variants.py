"""``cellctl bench classify``: latency, throughput and accuracy of each shipped variant.

For each variant (``fp32`` eager; ``fused`` = BN folded + frozen graph; ``int8`` = FX static
int8, measured for reference, not shipped because it is slower on this backbone) of the
external model, and side by side the combined ``detector`` (:mod:`cellctl.classify.fusion`,
when ``external.detect.pt`` exists: the whole per-image decision with its heat map): batch-1
latency p50/p95 over ``--n`` single-image calls (preprocessing
included: decode-free RGB → resize → normalise → forward → softmax), images/s at batch 16,
and accuracy on a fresh held-out set drawn from the same source as the training data
(seed 10000 + ``--seed``, never used for training).
fp32, fused and the detector are timed round-robin, call by call, so a load change during
the run hits all of them alike (``detector_vs_fused_p50`` is their ratio).

The detector runs twice side by side from the same file: ``detector`` on PyTorch (the traced
backbone, as before ONNX Runtime) and ``detector_onnx`` on ONNX Runtime
(:mod:`cellctl.classify.runtime`, at ``classifier.threads`` or its default), plus ORT at the
other thread count (``detector_onnx_<k>threads``); ``onnx_vs_torch`` counts identical labels on
the bench's images and ``setup.loadavg_during_latency`` the load around the timed loop.
``detector_with_reference``: the whole per-view decision of a commissioned plan (the ONNX detector fused
with the change map against the view's reference) beside the detector alone, on 20 twin pairs.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from cellctl.bench.options import BenchOptions

__all__ = ["bench_classify"]


def _timings(fn, images: list[np.ndarray], n: int) -> tuple[float, float]:
    for im in images[:5]:
        fn([im])
    ts = []
    for i in range(n):
        t = time.perf_counter()
        fn([images[i % len(images)]])
        ts.append(time.perf_counter() - t)
    ts_ms = np.array(ts) * 1000
    return float(np.percentile(ts_ms, 50)), float(np.percentile(ts_ms, 95))


def _interleaved(fns: dict[str, Any], images: list[np.ndarray], n: int) -> dict[str, tuple[float, float, float]]:
    """Batch-1 p50/p95/min (ms) of each function, timed round-robin: on shared cores the load drifts
    over a run, and timing one variant after the other would charge the drift to one of them. The
    fastest call is the one no other process pre-empted: what the work costs on an idle core."""
    for fn in fns.values():
        for im in images[:5]:
            fn([im])
    ts: dict[str, list[float]] = {k: [] for k in fns}
    for i in range(n):
        for k, fn in fns.items():
            t = time.perf_counter()
            fn([images[i % len(images)]])
            ts[k].append(time.perf_counter() - t)
    return {
        k: (float(np.percentile(v, 50)) * 1e3, float(np.percentile(v, 95)) * 1e3, min(v) * 1e3) for k, v in ts.items()
    }


def _shown(path: Path, root: Path) -> str:
    """``path`` relative to the project root when inside it (figures in git must not name a host's folders)."""
    try:
        return path.resolve().relative_to(root.resolve()).as_posix()
    except ValueError:
        return path.as_posix()


def _throughput(fn, images: list[np.ndarray], batch: int = 16, rounds: int = 8) -> float:
    b = (images * (batch // max(len(images), 1) + 1))[:batch]
    fn(b)
    t = time.perf_counter()
    for _ in range(rounds):
        fn(b)
    return batch * rounds / (time.perf_counter() - t)


def _int8(model: Any, calib: list[np.ndarray]) -> Any:
    import torch
    from torch.ao.quantization import get_default_qconfig_mapping
    from torch.ao.quantization.quantize_fx import convert_fx, prepare_fx

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        x = model.tensor(calib[:1])
        prepared = prepare_fx(model.net, get_default_qconfig_mapping("x86"), (x,))
        with torch.inference_mode():
            for s in range(0, len(calib), 16):
                prepared(model.tensor(calib[s : s + 16]))
        return convert_fx(prepared)


def _detectors(path: Path, surface: str, threads: int | None) -> dict[str, Any]:
    """Today's PyTorch detector and the ONNX Runtime one at ``classifier.threads`` (else its default),
    plus ORT at the other thread count on a multi-core host: the same file, side by side."""
    if not path.is_file():
        return {}
    from cellctl.classify.fusion import Detector
    from cellctl.classify.runtime import default_threads, onnx_path

    dets: dict[str, Any] = {"detector": Detector.load(path, surface=surface, runtime="torch")}
    if onnx_path(path).is_file():
        t = threads or default_threads()
        dets["detector_onnx"] = Detector.load(path, surface=surface, runtime="onnx", threads=t)
        if (os.cpu_count() or 1) > 1:
            other = 2 if t == 1 else 1
            dets[f"detector_onnx_{other}threads"] = Detector.load(path, surface=surface, runtime="onnx", threads=other)
    return dets


def _proba(det: Any) -> Any:
    def proba(ims: list[np.ndarray]) -> np.ndarray:
        return np.array([d.p_dirty for d in det.predict(ims)])

    return proba


def _agreement(ref: Any, other: Any, images: list[np.ndarray]) -> dict[str, Any]:
    """Same decisions? Labels and largest |Δp_dirty| of two detectors over the bench's images."""
    a, b = ref.predict(images), other.predict(images)
    return {
        "n": len(images),
        "labels_identical": sum(x.label == z.label for x, z in zip(a, b, strict=True)),
        "max_abs_p_dirty": float(max(abs(x.p_dirty - z.p_dirty) for x, z in zip(a, b, strict=True))),
    }


def _with_reference(cfg: Any, det: Any, surface: str, seed: int, n: int) -> dict[str, Any]:
    """The per-view decision a commissioned plan gets (issue 34): the detector (as the worker runs it) fused
    with the change map against the view's reference, timed interleaved with the detector alone on twin
    pairs at the demo's parking error (:func:`cellctl.bench.classify.reference.latency`). Target ≤ 15 ms."""
    from cellctl.bench.classify.pairs import make_pair_source
    from cellctl.bench.classify.reference import draw_pairs, latency
    from cellctl.classify.reference import ReferenceFusion, fusion_path

    path = fusion_path(cfg.path(cfg.classifier.models_dir), surface)
    if not path.is_file():
        return {"error": f"no reference fusion {str(path)!r}"}
    print("bench: per-view decision with the reference (twin pairs)", file=sys.stderr)
    pairs = draw_pairs(make_pair_source(surface, cfg), 20, 20_000 + seed, True)
    return {**latency(det, ReferenceFusion.load(path, surface), pairs, n), "pairs": len(pairs), "target_ms": 15.0}


def bench_classify(opts: BenchOptions) -> dict[str, Any]:
    """Measure every variant; returns ``{"fp32": {...}, "fused": {...}, "int8": {...}, "setup": {...}}``."""
    import torch

    from cellctl.classify.data import load_image, split_dataset
    from cellctl.classify.evaluate import metrics
    from cellctl.classify.infer import SurfaceModel
    from cellctl.classify.synth import synth_dataset

    cfg = opts.load_config()
    threads = cfg.classifier.threads or os.cpu_count() or 1
    torch.set_num_threads(threads)
    n = opts.n or 200
    surface = "external"
    path = cfg.path(cfg.classifier.models_dir) / f"{surface}.pt"
    base = SurfaceModel.load(path, surface=surface, variant="fp32")
    runs = (base.card or {}).get("data", {}).get("synth") or [{"source": "procedural", "size": 160}]
    source, size = runs[0].get("source", "procedural"), int(runs[0].get("size", 160))
    n_acc = max(40, min(n, 400))
    with tempfile.TemporaryDirectory(prefix="cellctl-bench-") as tmp:
        print(f"bench: drawing {n_acc} held-out {source} images", file=sys.stderr)
        synth_dataset(tmp, surface, n_acc, seed=10_000 + opts.seed, source=source, size=size, config=cfg)
        items = split_dataset(tmp, surface, fractions=(0.0, 0.0, 1.0)).test
        images = [load_image(p) for p, _ in items]
        y = np.array([lab for _, lab in items])
    out: dict[str, Any] = {}
    models: dict[str, Any] = {
        "fp32": base,
        "fused": SurfaceModel.load(path, surface=surface, variant="fused"),
    }
    fns: dict[str, Any] = {name: model.predict_proba for name, model in models.items()}
    dets = _detectors(cfg.path(cfg.classifier.models_dir) / f"{surface}.detect.pt", surface, cfg.classifier.threads)
    for name, det in dets.items():
        fns[name] = _proba(det)
        models[name] = det
    load_start = os.getloadavg()
    print(f"bench: batch-1 latency of {', '.join(fns)}, interleaved", file=sys.stderr)
    lat = _interleaved(fns, images, n)
    load_end = os.getloadavg()
    for name, fn in fns.items():
        p = fn(images)
        dec = models[name]
        out[name] = {
            "ms_p50": round(lat[name][0], 2),
            "ms_p95": round(lat[name][1], 2),
            "ms_min": round(lat[name][2], 2),
            "images_per_s_b16": round(_throughput(fn, images), 1),
            "accuracy": metrics(p, y, dec.threshold, dec.band)["accuracy"],
            "model_id": dec.model_id,
        }
        if name in dets:
            eng = dets[name].engine
            out[name]["runtime"] = eng.describe() if eng is not None else {"runtime": "torch", "threads": threads}
            out[name]["note"] = (
                "whole per-image decision: resize, fine-tuned backbone to block 10, patch head, "
                "memory-bank distances, fusion, calibration, heat map"
            )
    if "detector" in dets:
        out["detector_vs_fused_p50"] = round(lat["detector"][0] / lat["fused"][0], 3)
    if "detector_onnx" in dets:
        out["detector_onnx_vs_torch_p50"] = round(lat["detector_onnx"][0] / lat["detector"][0], 3)
        out["onnx_vs_torch"] = _agreement(dets["detector"], dets["detector_onnx"], images)
    if "detector_onnx" in dets:
        out["detector_with_reference"] = _with_reference(cfg, dets["detector_onnx"], surface, opts.seed, n)
    print("bench: int8 (reference)", file=sys.stderr)
    try:
        q = _int8(base, images[:64])

        def q_proba(ims: list[np.ndarray]) -> np.ndarray:
            with torch.inference_mode():
                logits = q(base.tensor(ims)).double()
                return torch.sigmoid((logits[:, 1] - logits[:, 0]) / base.temperature).numpy()

        p50, p95 = _timings(q_proba, images, max(10, n // 5))
        p = np.concatenate([q_proba(images[s : s + 32]) for s in range(0, len(images), 32)])
        out["int8"] = {
            "ms_p50": round(p50, 2),
            "ms_p95": round(p95, 2),
            "images_per_s_b16": round(_throughput(q_proba, images, rounds=2), 1),
            "accuracy": metrics(p, y, base.threshold, base.band)["accuracy"],
            "shipped": False,
            "note": "FX static int8 (x86); slower than fp32 for depthwise-conv Lite0",
        }
    except Exception as err:  # a quantization backend problem must not hide the other figures
        out["int8"] = {"error": f"{type(err).__name__}: {err}"}
    load = os.getloadavg()
    out["setup"] = {
        "loadavg_during_latency": {"start": [round(v, 2) for v in load_start], "end": [round(v, 2) for v in load_end]},
        "surface": surface,
        "model": _shown(Path(path), Path(cfg.root)),
        "input_px": base.input_size,
        "threads": threads,
        "threads_note": "torch threads (classifier.threads, default all cores); ONNX Runtime intra-op threads "
        "are in each detector_onnx entry (default runtime.default_threads(): 1 on 2 cores)",
        "onnx_session": "CPU EP, ORT_ENABLE_ALL, sequential, inter-op 1, no spinning (cellctl.classify.runtime)",
        "cpu_count": os.cpu_count(),
        "loadavg_1m": round(load[0], 2),
        "n_latency": n,
        "n_accuracy": len(y),
        "accuracy_source": source,
        "torch": torch.__version__,
        "note": "batch-1 times include resize+normalise; CPU shared with other processes (see loadavg)",
    }
    return out
