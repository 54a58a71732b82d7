"""Inference: a trained surface model loaded once, batched prediction, labels with uncertainty.

Variants:

* ``fp32`` — the eager float32 model.
* ``fused`` — the same weights with batch norm folded into the convolutions and the graph
  frozen (``torch.jit.freeze(torch.jit.trace(...))``): identical outputs to ~1e-6, faster at
  batch 1. (Static int8 was measured and is *slower* for EfficientNet-Lite0 on x86 — its
  depthwise convolutions have no fast int8 kernel — see docs/decisions.md.)
"""

from __future__ import annotations

import json
import math
import stat
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from cellctl.classify.collect import LABELS, SURFACES, check_surface
from cellctl.classify.data import prepare
from cellctl.classify.decision import is_uncertain
from cellctl.classify.nets import ARCHS, build_model
from cellctl.errors import ClassifierError
from cellctl.hashing import bytes_sha256

__all__ = ["VARIANTS", "Prediction", "SurfaceModel", "load_surface_models"]

VARIANTS = ("fp32", "fused")
WEIGHTS_FORMAT = "cellctl-classifier/1"
MAX_WEIGHTS_BYTES = 512 * 1024 * 1024
"""Largest weights file read (lite0 is ~7 MB, resnet18 ~23 MB in fp16)."""
MAX_CARD_BYTES = 1024 * 1024


def _number(x: Any, lo: float = -math.inf, hi: float = math.inf) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) and lo <= x <= hi


def _blob_problem(blob: dict[str, Any]) -> str | None:
    """What is wrong with the metadata and tensors of a weights blob whose format is ours, or None."""
    sd = blob.get("state_dict")
    if not isinstance(sd, dict) or not all(isinstance(k, str) and torch.is_tensor(v) for k, v in sd.items()):
        return "state_dict is not a mapping of parameter names to tensors"
    size = blob.get("input_size")
    if not (isinstance(size, int) and not isinstance(size, bool) and 16 <= size <= 1024):
        return f"input_size is {size!r:.40}, expected an integer in [16, 1024] pixels"
    for key, lo in (("mean", -math.inf), ("std", 1e-6)):
        v = blob.get(key)
        if not (isinstance(v, list | tuple) and len(v) == 3 and all(_number(x, lo) for x in v)):
            return f"{key} is {v!r:.60}, expected 3 finite numbers" + (" > 0" if key == "std" else "")
    if not _number(blob.get("threshold"), 0.0, 1.0):
        return f"threshold is {blob.get('threshold')!r:.40}, expected a number in [0, 1]"
    if not _number(blob.get("uncertain_logit_band"), 0.0):
        return f"uncertain_logit_band is {blob.get('uncertain_logit_band')!r:.40}, expected a number >= 0"
    if not _number(blob.get("temperature", 1.0), 1e-6):
        return f"temperature is {blob.get('temperature')!r:.40}, expected a number > 0"
    return None


@dataclass(frozen=True)
class Prediction:
    """One image's result."""

    label: str
    p_dirty: float
    uncertain: bool
    model_id: str

    def as_dict(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "p_dirty": self.p_dirty,
            "uncertain": self.uncertain,
            "model_id": self.model_id,
        }


class SurfaceModel:
    """A surface's trained network with its preprocessing and decision rule.

    Use :meth:`load`. ``predict`` takes RGB uint8 images of any size (resized to the model's
    input) and is thread-safe for concurrent callers (inference mode, no state).
    """

    def __init__(
        self,
        net: nn.Module,
        *,
        surface: str,
        arch: str,
        input_size: int,
        mean: list[float],
        std: list[float],
        threshold: float,
        band: float,
        model_id: str,
        card: dict[str, Any] | None,
        variant: str,
        temperature: float = 1.0,
    ) -> None:
        self.net = net
        self.surface = surface
        self.arch = arch
        self.input_size = input_size
        self.mean = torch.tensor(mean, dtype=torch.float32).view(1, 3, 1, 1)
        self.std = torch.tensor(std, dtype=torch.float32).view(1, 3, 1, 1)
        self.threshold = float(threshold)
        self.band = float(band)
        self.model_id = model_id
        self.card = card
        self.variant = variant
        self.temperature = float(temperature)

    @classmethod
    def load(cls, path: Path | str, *, surface: str | None = None, variant: str = "fp32") -> SurfaceModel:
        """Load ``<surface>.pt`` (and its card ``<surface>.json`` if present).

        Raises:
            ClassifierError: missing/unreadable file, a file of another format or surface, or
                weights that do not fit the recorded architecture.
        """
        p = Path(path)
        if variant not in VARIANTS:
            raise ClassifierError(f"variant {variant!r} is unknown; expected one of {list(VARIANTS)}")
        if not p.exists() and not p.is_symlink():  # a symlink loop "does not exist" but must say so
            raise ClassifierError(
                f"classifier weights {str(p)!r} do not exist; train them with "
                f"`cellctl train --surface {surface or p.stem} --data DIR --out {p}`"
            )
        try:
            st = p.stat()
            if not stat.S_ISREG(st.st_mode):  # a FIFO would block the worker's start forever
                raise ClassifierError(f"classifier weights {str(p)!r} is not a regular file")
            if st.st_size == 0:
                raise ClassifierError(
                    f"classifier weights {str(p)!r} is empty; expected a file saved by `cellctl train`"
                )
            if st.st_size > MAX_WEIGHTS_BYTES:
                raise ClassifierError(
                    f"classifier weights {str(p)!r} has {st.st_size} bytes; expected at most {MAX_WEIGHTS_BYTES}"
                )
            raw = p.read_bytes()
        except OSError as err:
            raise ClassifierError(f"classifier weights {str(p)!r} cannot be read: {err}") from err
        try:
            import io

            blob = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
        except Exception as err:  # torch raises many kinds for a damaged file
            first = (str(err).strip().splitlines() or [type(err).__name__])[0][:300]
            raise ClassifierError(
                f"classifier weights {str(p)!r} cannot be read as a torch file saved by `cellctl train`: {first}"
            ) from err
        if not isinstance(blob, dict) or blob.get("format") != WEIGHTS_FORMAT:
            got = blob.get("format") if isinstance(blob, dict) else type(blob).__name__
            raise ClassifierError(
                f"{str(p)!r} is not a cellctl classifier file (format {got!r}, expected {WEIGHTS_FORMAT!r})"
            )
        if surface is not None and blob.get("surface") != surface:
            raise ClassifierError(f"{str(p)!r} is a model for surface {blob.get('surface')!r}, expected {surface!r}")
        arch = blob.get("arch")
        if not isinstance(arch, str) or arch not in ARCHS:
            raise ClassifierError(f"{str(p)!r} records architecture {arch!r:.40}; expected one of {list(ARCHS)}")
        problem = _blob_problem(blob)
        if problem is not None:
            raise ClassifierError(f"{str(p)!r} is not a usable cellctl classifier file: {problem}")
        net = build_model(arch, pretrained=False)
        sd = {k: (v.float() if v.is_floating_point() else v) for k, v in blob["state_dict"].items()}
        try:
            net.load_state_dict(sd, strict=True)
        except RuntimeError as err:
            raise ClassifierError(f"{str(p)!r} weights do not fit {arch}: {str(err)[:400]}") from err
        net.eval()
        size = int(blob["input_size"])
        sha = bytes_sha256(raw)  # the bytes torch.load read: the digest is of what was loaded
        card = None
        card_path = p.with_suffix(".json")
        if card_path.is_file():
            try:
                if card_path.stat().st_size > MAX_CARD_BYTES:
                    raise ClassifierError(f"model card {str(card_path)!r} is larger than {MAX_CARD_BYTES} bytes")
                card = json.loads(card_path.read_bytes())
            except (OSError, ValueError, RecursionError) as err:
                raise ClassifierError(f"model card {str(card_path)!r} is not valid JSON: {err}") from err
            if not isinstance(card, dict):
                raise ClassifierError(
                    f"model card {str(card_path)!r} holds a JSON {type(card).__name__}, expected an object"
                )
            if card.get("sha256") not in (None, sha):
                raise ClassifierError(
                    f"model card {str(card_path)!r} is for weights sha256 {str(card.get('sha256'))[:12]}…, "
                    f"but {p.name} has {sha[:12]}… (card and weights do not belong together)"
                )
        if variant == "fused":
            with torch.inference_mode(), warnings.catch_warnings():
                warnings.simplefilter("ignore")
                net = torch.jit.freeze(torch.jit.trace(net, torch.zeros(1, 3, size, size)))
        model_id = f"{blob['surface']}-{arch}-{sha[:12]}" + ("" if variant == "fp32" else f"-{variant}")
        return cls(
            net,
            surface=str(blob["surface"]),
            arch=arch,
            input_size=size,
            mean=list(blob["mean"]),
            std=list(blob["std"]),
            threshold=float(blob["threshold"]),
            band=float(blob["uncertain_logit_band"]),
            model_id=model_id,
            card=card,
            variant=variant,
            temperature=float(blob.get("temperature", 1.0)),
        )

    def tensor(self, images: list[NDArray[np.uint8]]) -> torch.Tensor:
        """Preprocess RGB uint8 images into a normalised batch ``(N, 3, S, S)``."""
        x = torch.from_numpy(np.stack([prepare(im, self.input_size) for im in images]))
        return (x - self.mean) / self.std

    def predict_proba(self, images: list[NDArray[np.uint8]], batch: int = 32) -> NDArray[np.float64]:
        """``p_dirty`` of each image."""
        out = []
        with torch.inference_mode():
            for s in range(0, len(images), batch):
                logits = self.net(self.tensor(images[s : s + batch])).double()
                z = (logits[:, 1] - logits[:, 0]) / self.temperature
                out.append(torch.sigmoid(z).numpy())
        return np.concatenate(out) if out else np.zeros(0)

    def predict(self, images: list[NDArray[np.uint8]]) -> list[Prediction]:
        """Label, ``p_dirty`` and uncertainty of each image."""
        p = self.predict_proba(images)
        unc = is_uncertain(p, self.threshold, self.band)
        return [
            Prediction(LABELS[int(pi >= self.threshold)], float(pi), bool(u), self.model_id)
            for pi, u in zip(p, unc, strict=True)
        ]


def load_surface_models(
    models_dir: Path | str, variant: str = "fp32"
) -> tuple[dict[str, SurfaceModel], dict[str, str]]:
    """Load every surface's model from ``models_dir/<surface>.pt``.

    Returns:
        ``(models, problems)``: the models that loaded and, for the others, why not (so a
        worker can still serve the surfaces it has and explain the missing one per request).
    """
    models: dict[str, SurfaceModel] = {}
    problems: dict[str, str] = {}
    for s in SURFACES:
        try:
            models[s] = SurfaceModel.load(Path(models_dir) / f"{s}.pt", surface=check_surface(s), variant=variant)
        except ClassifierError as err:
            problems[s] = str(err)
    return models, problems
