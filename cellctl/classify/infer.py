"""Inference: a trained surface model loaded once, batched prediction, labels with uncertainty.

Variants:

* ``fp32`` — the eager float32 model.
* ``fused`` — the same weights with batch norm folded into the convolutions and the graph
  frozen (``torch.jit.freeze(torch.jit.trace(...))``): identical outputs to ~1e-6, faster at
  batch 1. (Static int8 was measured and is *slower* for EfficientNet-Lite0 on x86 — its
  depthwise convolutions have no fast int8 kernel — see docs/decisions.md.)
"""

from __future__ import annotations

import hashlib
import json
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
from cellctl.classify.evaluate import is_uncertain
from cellctl.classify.nets import ARCHS, build_model
from cellctl.errors import ClassifierError

__all__ = ["VARIANTS", "Prediction", "SurfaceModel", "load_surface_models"]

VARIANTS = ("fp32", "fused")
WEIGHTS_FORMAT = "cellctl-classifier/1"


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
        if not p.is_file():
            raise ClassifierError(
                f"classifier weights {str(p)!r} do not exist; train them with "
                f"`cellctl train --surface {surface or p.stem} --data DIR --out {p}`"
            )
        raw = p.read_bytes()
        try:
            import io

            blob = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
        except Exception as err:  # torch raises many kinds for a damaged file
            raise ClassifierError(f"classifier weights {str(p)!r} cannot be read: {err}") from err
        if not isinstance(blob, dict) or blob.get("format") != WEIGHTS_FORMAT:
            got = blob.get("format") if isinstance(blob, dict) else type(blob).__name__
            raise ClassifierError(
                f"{str(p)!r} is not a cellctl classifier file (format {got!r}, expected {WEIGHTS_FORMAT!r})"
            )
        if surface is not None and blob.get("surface") != surface:
            raise ClassifierError(f"{str(p)!r} is a model for surface {blob.get('surface')!r}, expected {surface!r}")
        arch = blob.get("arch")
        if arch not in ARCHS:
            raise ClassifierError(f"{str(p)!r} records architecture {arch!r}; expected one of {list(ARCHS)}")
        net = build_model(arch, pretrained=False)
        sd = {k: (v.float() if v.is_floating_point() else v) for k, v in blob["state_dict"].items()}
        try:
            net.load_state_dict(sd, strict=True)
        except RuntimeError as err:
            raise ClassifierError(f"{str(p)!r} weights do not fit {arch}: {str(err)[:400]}") from err
        net.eval()
        size = int(blob["input_size"])
        sha = hashlib.sha256(raw).hexdigest()
        card = None
        card_path = p.with_suffix(".json")
        if card_path.is_file():
            try:
                card = json.loads(card_path.read_text())
            except json.JSONDecodeError as err:
                raise ClassifierError(f"model card {str(card_path)!r} is not valid JSON: {err}") from err
            if card.get("sha256") not in (None, sha):
                raise ClassifierError(
                    f"model card {str(card_path)!r} is for weights sha256 {card.get('sha256', '')[:12]}…, "
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
