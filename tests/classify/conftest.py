"""Classifier fixtures: a small procedural dataset and a tiny trained model (once per session)."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def tiny_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """48 procedural external + internal images at 64 px (seeded)."""
    from cellctl.classify.synth import synth_dataset

    root = tmp_path_factory.mktemp("cls_data")
    for surface in ("external", "internal"):
        synth_dataset(root, surface, 48, seed=3, source="procedural", size=64)
    return root


@pytest.fixture(scope="session")
def tiny_models(tiny_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``external.pt`` and ``internal.pt`` trained for a few epochs at 64 px input."""
    from cellctl.classify.train import train

    out = tmp_path_factory.mktemp("cls_models")
    for surface in ("external", "internal"):
        train(tiny_data, surface, out / f"{surface}.pt", input_size=64, max_epochs=(4, 1), threads=2, seed=1)
    return out
