"""ONNX Runtime for the detector: the export made at build time and the session that runs it.

PyTorch trains; ONNX Runtime (CPU) decides. ``cellctl detector export --surface S`` (also run at the
end of ``cellctl detector train``) writes ``<surface>.detect.onnx`` beside ``<surface>.detect.pt``:
the detector's backbone pass (fine-tuned Lite0 stem + blocks 0–10, grey world and normalisation
inside) and its patch head, exported from the ``.pt``'s own weights, plus the memory-bank search as
graph operations whose **bank is an input**, not a weight. The file therefore depends only on the
networks: a site-enrolled detector (:mod:`cellctl.classify.enroll`) whose bank and statistics differ
but whose networks are the base's runs on the base's export. At load the bank inputs are turned into
constants of the in-memory model, so ONNX Runtime pre-packs the bank for its matrix product (a
distance ``|q|² + min_k(|b_k|² − 2 q·b_k)`` over 1024 entries is one GEMM of 256 × 176 × 1024).
Fusion, Platt scaling and the heat map stay in numpy (:meth:`~cellctl.classify.fusion.Detector.scores`).

Freshness: the export records ``net_sha256``, a digest of the backbone and head tensors it was
made from (and the ``.pt`` file's sha256 for the record). A session is only built when the digest
equals the loaded file's; a ``.onnx`` beside a ``.pt`` whose networks changed (retrained, not
re-exported) is refused with the command that fixes it. The export itself is refused unless ORT and
PyTorch agree on a fixed batch (:func:`parity`): maps within :data:`PARITY_ATOL`, identical labels.

Runtime choice (``classifier.runtime``): ``onnx`` (an export must exist and match), ``torch``, or
``auto`` (the default: the export when one is there; a stale one is still an error).
"""

from __future__ import annotations

import copy
import datetime as _dt
import hashlib
import json
import logging
import os
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import ClassifierError
from cellctl.hashing import file_sha256

if TYPE_CHECKING:
    import torch

    from cellctl.classify.fusion import Detector

__all__ = [
    "ONNX_FORMAT",
    "PARITY_ATOL",
    "RUNTIMES",
    "OnnxMaps",
    "attach_runtime",
    "default_threads",
    "export_detector",
    "net_sha256",
    "onnx_path",
    "parity",
    "parity_images",
]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

RUNTIMES = ("auto", "onnx", "torch")
ONNX_FORMAT = "cellctl-detector-onnx/1"
OPSET = 17
PARITY_ATOL = 1e-3
"""Largest |ORT − PyTorch| allowed on the logit and distance maps (both O(10); fp32 reordering
gives ~1e-5) and on ``p_dirty``; labels must be identical."""
BANK_INPUTS = ("bank_t_neg2", "bank_sq", "feat_mean", "feat_std")
MAX_ONNX_BYTES = 64 * 1024 * 1024


def onnx_path(pt: Path | str) -> Path:
    """The export beside a detector file: ``external.detect.pt`` → ``external.detect.onnx``."""
    p = Path(pt)
    return p.with_name((p.name[:-3] if p.name.endswith(".pt") else p.name) + ".onnx")


def net_sha256(blob: dict[str, Any]) -> str:
    """Digest of the networks an export computes (backbone + patch head tensors, names and shapes),
    independent of the bank, statistics and thresholds that enrollment or a refit change."""
    import torch

    h = hashlib.sha256()
    for part in ("backbone", "head"):
        state = blob.get(part)
        if not isinstance(state, dict):
            raise ClassifierError(f"detector has no {part!r} state to export (format {blob.get('format')!r})")
        for k in sorted(state):
            t = state[k].detach().to(torch.float32).contiguous()
            h.update(f"{part}.{k}:{tuple(t.shape)};".encode())
            h.update(t.numpy().tobytes())
    return h.hexdigest()


def default_threads() -> int:
    """Intra-op threads when ``classifier.threads`` is unset: 1 on a 2-core host, else 2.

    One thread already meets the 10 ms budget (~4 ms for the whole decision), costs the least CPU per
    image (no hand-offs between threads) and leaves the other core to the supervisor, the camera and
    the twin, which run during a scan; ``cellctl bench classify`` also times the other count."""
    return 1 if (os.cpu_count() or 1) <= 2 else 2


# --- export (build time, needs torch) ----------------------------------------------------------


def _graph_module(blob: dict[str, Any]) -> Any:
    """The exported computation: image batch + bank → patch logits and patch distances ``(N, P)``."""
    from torch import nn

    from cellctl.classify.anomaly import PatchFeatures
    from cellctl.classify.fusion import _head  # the one definition of the head's layout

    feats = PatchFeatures()
    feats.load_state_dict({k: v.float() for k, v in blob["backbone"].items()})
    net_head = _head()
    net_head.load_state_dict({k: v.float() for k, v in blob["head"].items()})

    class DecisionGraph(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.features = feats
            self.head = net_head.eval()

        def forward(
            self,
            x: torch.Tensor,
            bank_t_neg2: torch.Tensor,
            bank_sq: torch.Tensor,
            mean: torch.Tensor,
            std: torch.Tensor,
        ) -> tuple[torch.Tensor, torch.Tensor]:
            raw = self.features(x)
            f = (raw - mean.view(1, -1, 1, 1)) / std.view(1, -1, 1, 1)
            s = self.head(raw)[:, 0].flatten(1)
            q = f.flatten(2).transpose(1, 2)  # (N, P, D)
            # |q - b|² = |q|² + |b|² - 2 q·b; the bank comes pre-scaled by -2 (exact in floating point)
            d2 = (q * q).sum(2) + (bank_sq + q @ bank_t_neg2).amin(2)
            return s, d2.clamp_min(0.0).sqrt()

    return DecisionGraph().eval()


def _bank_arrays(bank: Any, mean: Any, std: Any) -> dict[str, NDArray[np.float32]]:
    """The graph's bank inputs from a bank ``(K, D)`` and its channel statistics ``(D,)``."""
    b = np.asarray(bank, np.float32)
    return {
        "bank_t_neg2": np.ascontiguousarray(-2.0 * b.T, np.float32),
        "bank_sq": (b.astype(np.float32) ** 2).sum(1).astype(np.float32),
        "feat_mean": np.asarray(mean, np.float32).reshape(-1),
        "feat_std": np.asarray(std, np.float32).reshape(-1),
    }


def _detector_bank(det: Detector) -> dict[str, NDArray[np.float32]]:
    mb = det.bank
    return _bank_arrays(mb.bank.numpy(), mb.mean.numpy(), mb.std.numpy())


def parity_images(surface: str, n: int = 8, seed: int = 0, size: int = 192) -> list[NDArray[np.uint8]]:
    """A fixed, seeded batch: close-up steel of ``surface``, every other image with a training
    contamination family under training optics (clean and dirty, so both labels are exercised)."""
    from cellctl.classify.contamination import FAMILIES, Optics, closeup_steel, composite, draw_family, optics

    rng = np.random.default_rng(seed)
    fams = sorted(FAMILIES)
    out = []
    for i in range(n):
        img = closeup_steel(surface, size, size, rng)
        if i % 2:
            img, _ = composite(img, draw_family(fams[(i // 2) % len(fams)], size, size, rng))
        out.append(optics(img, Optics.draw(rng)))
    return out


def parity(torch_det: Detector, onnx_det: Detector, images: list[NDArray[np.uint8]]) -> dict[str, Any]:
    """Largest |ORT − PyTorch| on the logit map, the distance map and ``p_dirty`` of ``images``,
    and how many labels differ."""
    import torch

    with torch.inference_mode():
        x = torch_det.tensor(images)
        st, at = torch_det.maps(x)
        so, ao = onnx_det.maps(x)
        pt, po = torch_det.scores(st, at)["p"], onnx_det.scores(so, ao)["p"]
    lt, lo = pt >= torch_det.threshold, po >= onnx_det.threshold
    return {
        "n": len(images),
        "max_abs_logit": float((st - so).abs().max()),
        "max_abs_distance": float((at - ao).abs().max()),
        "max_abs_p_dirty": float(np.abs(pt - po).max()),
        "labels_differ": int((lt != lo).sum()),
        "dirty": int(lt.sum()),
    }


def _parity_ok(par: dict[str, Any]) -> bool:
    return (
        max(par["max_abs_logit"], par["max_abs_distance"], par["max_abs_p_dirty"]) <= PARITY_ATOL
        and par["labels_differ"] == 0
    )


def export_detector(pt: Path | str, out: Path | str | None = None, command: str | None = None) -> dict[str, Any]:
    """Export a format-2 detector's networks to ONNX (default :func:`onnx_path`), check parity on
    :func:`parity_images`, write the file atomically and record it in the ``.pt``'s card (``onnx``).

    Raises:
        ClassifierError: unreadable or format-1 detector, or ORT and PyTorch disagree (nothing written).

    Returns:
        What the card records: file, sha256, bytes, net_sha256, parity, versions.
    """
    import onnx
    import onnxruntime
    import torch

    from cellctl.classify.fusion import Detector

    src = Path(pt)
    dst = Path(out) if out is not None else onnx_path(src)
    ref = Detector.load(src, runtime="torch")
    blob = torch.load(src, map_location="cpu", weights_only=True)
    if "backbone" not in blob:
        raise ClassifierError(f"{str(src)!r} is a format-1 detector (frozen ImageNet backbone): retrain it to export")
    digest = net_sha256(blob)
    bank = _detector_bank(ref)
    size = int(blob.get("input_size", 128))
    inputs = (torch.zeros(1, 3, size, size), *(torch.from_numpy(bank[k]) for k in BANK_INPUTS))
    tmp = dst.with_name(dst.name + ".tmp")
    dst.parent.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings(), torch.inference_mode():
        # the TorchScript exporter: a static conv graph needs no dynamo/onnxscript, and it is
        # deprecated, not gone, in the torch range pyproject.toml allows
        warnings.simplefilter("ignore")
        torch.onnx.export(
            _graph_module(blob),
            inputs,
            str(tmp),
            dynamo=False,
            opset_version=OPSET,
            input_names=["x", *BANK_INPUTS],
            output_names=["logit", "distance"],
            dynamic_axes={
                "x": {0: "n"},
                "logit": {0: "n"},
                "distance": {0: "n"},
                "bank_t_neg2": {1: "k"},
                "bank_sq": {0: "k"},
            },
        )
    model = onnx.load(str(tmp))
    meta = {
        "format": ONNX_FORMAT,
        "surface": str(blob["surface"]),
        "input_size": str(size),
        "net_sha256": digest,
        "source_sha256": file_sha256(src),
        "source": src.name,
    }
    for k, v in meta.items():
        model.metadata_props.add(key=k, value=v)
    onnx.checker.check_model(model)
    onnx.save(model, str(tmp))
    trial = copy.copy(ref)  # the same detector, its networks run by ORT
    trial.engine = _session_for(tmp, digest, bank, threads=1)
    par = parity(ref, trial, parity_images(str(blob["surface"])))
    if not _parity_ok(par):
        tmp.unlink(missing_ok=True)
        raise ClassifierError(f"ONNX export of {str(src)!r} disagrees with PyTorch (tolerance {PARITY_ATOL}): {par}")
    os.replace(tmp, dst)
    info = {
        "file": dst.name,
        "sha256": file_sha256(dst),
        "bytes": dst.stat().st_size,
        "format": ONNX_FORMAT,
        "opset": OPSET,
        "net_sha256": digest,
        "source_sha256": meta["source_sha256"],
        "command": command or f"cellctl detector export --surface {blob['surface']}",
        "exported": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "parity": {**par, "tolerance": PARITY_ATOL, "images": "runtime.parity_images(surface, 8, seed 0)"},
        "versions": {"torch": torch.__version__, "onnx": onnx.__version__, "onnxruntime": onnxruntime.__version__},
    }
    card_path = src.with_suffix(".json")
    if card_path.is_file() and dst.parent == src.parent:
        card = json.loads(card_path.read_text())
        card["onnx"] = info
        card_path.write_text(json.dumps(card, indent=2) + "\n")
    return info


# --- inference ---------------------------------------------------------------------------------


def _read_meta(path: Path) -> tuple[Any, dict[str, str]]:
    import onnx

    try:
        size = path.stat().st_size
        if not 0 < size <= MAX_ONNX_BYTES:
            raise ClassifierError(f"ONNX file {str(path)!r} has {size} bytes, expected 1..{MAX_ONNX_BYTES}")
        model = onnx.load(str(path))
    except ClassifierError:
        raise
    except Exception as err:  # protobuf and OS errors alike: a damaged or foreign file
        raise ClassifierError(f"ONNX file {str(path)!r} cannot be read: {str(err)[:200]}") from err
    meta = {p.key: p.value for p in model.metadata_props}
    if meta.get("format") != ONNX_FORMAT:
        raise ClassifierError(f"{str(path)!r} is not a cellctl detector export (format {meta.get('format')!r})")
    return model, meta


class OnnxMaps:
    """The detector's network pass and bank search in one ONNX Runtime session.

    Called like :meth:`~cellctl.classify.fusion.Detector.maps`: a batch ``(N, 3, S, S)`` in [0, 1]
    → patch logit map and patch distance map ``(N, G, G)`` (torch tensors sharing ORT's buffers).
    """

    def __init__(self, session: Any, path: Path, threads: int) -> None:
        self.session = session
        self.path = path
        self.threads = threads
        self.sha256 = file_sha256(path)

    def __call__(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        import torch

        arr = x.numpy()
        if arr.dtype != np.float32 or not arr.flags.c_contiguous:
            arr = np.ascontiguousarray(arr, np.float32)
        s, a = self.session.run(None, {"x": arr})
        n, p = s.shape
        g = int(round(p**0.5))
        return torch.from_numpy(s).view(n, g, g), torch.from_numpy(a).view(n, g, g)

    def describe(self) -> dict[str, Any]:
        """What the worker and the benches report: file, its sha256 and the session's threads."""
        import onnxruntime

        return {
            "runtime": "onnx",
            "file": self.path.name,
            "sha256": self.sha256,
            "intra_op_threads": self.threads,
            "onnxruntime": onnxruntime.__version__,
        }


def _session_for(
    path: Path, digest: str, bank: dict[str, NDArray[np.float32]], threads: int | None, model: Any = None
) -> OnnxMaps:
    """An ORT session of the export at ``path`` with ``bank`` folded in as constants."""
    import onnxruntime as ort
    from onnx import numpy_helper

    if model is None:
        model, meta = _read_meta(path)
        if meta.get("net_sha256") != digest:
            raise ClassifierError(f"{str(path)!r} was exported from other networks (net_sha256 mismatch)")
    graph = model.graph
    keep = [i for i in graph.input if i.name not in BANK_INPUTS]
    del graph.input[:]
    graph.input.extend(keep)
    graph.initializer.extend(numpy_helper.from_array(bank[k], k) for k in BANK_INPUTS)
    n = threads or default_threads()
    so = ort.SessionOptions()
    so.intra_op_num_threads = n
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    # ENABLE_ALL adds the NCHWc layout transform: 2.5 ms instead of 6 ms for the backbone at 1 thread
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    # no busy-waiting workers: on 2 shared cores a spinning pool took 13 ms instead of 4 at load 1
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    so.log_severity_level = 3
    try:
        sess = ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])
    except Exception as err:  # ORT raises its own exception types for invalid graphs
        raise ClassifierError(f"ONNX file {str(path)!r} cannot be run: {str(err)[:200]}") from err
    return OnnxMaps(sess, path, n)


def attach_runtime(
    det: Detector,
    blob: dict[str, Any],
    path: Path | str,
    runtime: str = "auto",
    threads: int | None = None,
    also: tuple[Path, ...] = (),
) -> None:
    """Give ``det`` (loaded from ``path``) an ONNX Runtime session when ``runtime`` asks for one.

    Looks at the export beside ``path`` first, then ``also`` (e.g. the shipped detector's export
    for a site-enrolled file); an export is used only when its ``net_sha256`` is this file's.

    Raises:
        ClassifierError: unknown runtime; the export beside ``path`` is stale or unreadable;
            ``runtime`` is ``onnx`` and no export matches.
    """
    if runtime not in RUNTIMES:
        raise ClassifierError(f"classifier runtime {runtime!r} is unknown; expected one of {list(RUNTIMES)}")
    det.engine = None
    if runtime == "torch":
        return
    p = Path(path)
    surface = str(blob.get("surface"))
    fix = f"`cellctl detector export --surface {surface}`"
    if "backbone" not in blob:
        if runtime == "onnx":
            raise ClassifierError(f"{str(p)!r} is a format-1 detector: it has no ONNX export (retrain it)")
        return
    digest = net_sha256(blob)
    own = onnx_path(p)
    for cand in (own, *also):
        if not cand.is_file():
            continue
        model, meta = _read_meta(cand)
        if meta.get("net_sha256") != digest:
            if cand == own:
                raise ClassifierError(
                    f"ONNX export {str(cand)!r} is stale: it was made from other networks than {p.name} "
                    f"(net_sha256 {meta.get('net_sha256', '?')[:12]}…, the file's {digest[:12]}…); run {fix}"
                )
            continue
        if meta.get("surface") != surface:
            raise ClassifierError(f"ONNX export {str(cand)!r} is for {meta.get('surface')!r}, expected {surface!r}")
        det.engine = _session_for(cand, digest, _detector_bank(det), threads, model)
        return
    if runtime == "onnx":
        raise ClassifierError(
            f"classifier.runtime is 'onnx' but {str(p)!r} has no ONNX export ({str(own)!r} missing); run {fix}"
        )
    log.info("detector %s: no ONNX export beside it, PyTorch runs it", p.name)
