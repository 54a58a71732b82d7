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
PyTorch agree on a fixed batch (:func:`cellctl.classify.onnx_export.parity`): maps within
:data:`PARITY_ATOL`, identical labels.

Runtime choice (``classifier.runtime``): ``onnx`` (an export must exist and match), ``torch``, or
``auto`` (the default: the export when one is there; a stale one is still an error).
"""

from __future__ import annotations

import hashlib
import logging
import os
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
    "net_sha256",
    "onnx_path",
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
