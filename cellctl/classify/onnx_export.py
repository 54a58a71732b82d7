"""The ONNX export of a detector and its parity check against PyTorch (build and training time).

Split from :mod:`cellctl.classify.runtime` (which runs the export and is imported by
:meth:`~cellctl.classify.fusion.Detector.load`): exporting loads a detector through
:mod:`cellctl.classify.fusion`, so keeping it apart leaves no import cycle between the two.
What the export holds and why: :mod:`cellctl.classify.runtime`.
"""

from __future__ import annotations

import copy
import datetime as _dt
import json
import os
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from cellctl.classify.runtime import (
    BANK_INPUTS,
    ONNX_FORMAT,
    OPSET,
    PARITY_ATOL,
    _detector_bank,
    _session_for,
    net_sha256,
    onnx_path,
)
from cellctl.errors import ClassifierError
from cellctl.hashing import file_sha256

if TYPE_CHECKING:
    import torch

    from cellctl.classify.fusion import Detector

__all__ = ["export_detector", "parity", "parity_images"]


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
        "parity": {**par, "tolerance": PARITY_ATOL, "images": "onnx_export.parity_images(surface, 8, seed 0)"},
        "versions": {"torch": torch.__version__, "onnx": onnx.__version__, "onnxruntime": onnxruntime.__version__},
    }
    card_path = src.with_suffix(".json")
    if card_path.is_file() and dst.parent == src.parent:
        card = json.loads(card_path.read_text())
        card["onnx"] = info
        card_path.write_text(json.dumps(card, indent=2) + "\n")
    return info


# --- inference ---------------------------------------------------------------------------------
