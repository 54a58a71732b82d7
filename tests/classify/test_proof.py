"""``cellctl detector proof``: exact binomial intervals, and the command end to end on a few images."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cellctl.classify.proof import clopper_pearson, rate, rate_figures
from cellctl.errors import ClassifierError

ROOT = Path(__file__).resolve().parents[2]


def test_clopper_pearson_matches_known_values() -> None:
    """Published exact intervals: 0/10 -> [0, 1 - 0.025^(1/10)], 5/10 -> [0.1871, 0.8129]; the
    issue's one-sided 95 % bounds: 0 misses in 299 and 1 miss in 473 are both ~1 %."""
    lo, hi = clopper_pearson(0, 10)
    assert lo == 0.0 and hi == pytest.approx(1 - 0.025**0.1, abs=1e-9)
    lo, hi = clopper_pearson(5, 10)
    assert (lo, hi) == (pytest.approx(0.18709, abs=1e-5), pytest.approx(0.81291, abs=1e-5))
    assert clopper_pearson(10, 10) == (pytest.approx(0.025**0.1, abs=1e-9), 1.0)
    assert rate(0, 299)["upper95"] == pytest.approx(0.01, abs=2e-4)
    assert rate(1, 473)["upper95"] == pytest.approx(0.01, abs=2e-4)
    assert rate(0, 0)["rate"] is None
    with pytest.raises(ClassifierError, match="k=3, n=2"):
        clopper_pearson(3, 2)


def test_rate_figures_count_false_clean_and_false_dirty() -> None:
    p = np.array([0.9, 0.2, 0.8, 0.1, 0.6])
    y = np.array([1, 1, 0, 0, 1])
    f = rate_figures(p, y, 0.5)
    assert f["false_clean"]["k"] == 1 and f["false_clean"]["n"] == 3
    assert f["false_dirty"]["k"] == 1 and f["false_dirty"]["n"] == 2
    assert f["accuracy"]["k"] == 3 and f["accuracy"]["n"] == 5


def _intervals(node: object) -> list[dict]:
    """Every rate object in a JSON tree."""
    if isinstance(node, dict):
        own = [node] if {"k", "n", "rate", "ci95"} <= node.keys() else []
        return own + [r for v in node.values() for r in _intervals(v)]
    if isinstance(node, list):
        return [r for v in node for r in _intervals(v)]
    return []


@pytest.mark.timeout(900)  # ~1 CPU min; the shared cores run it at a fraction of that
def test_proof_quick_runs_end_to_end(tmp_path: Path) -> None:
    """--quick: every section is generated and scored; every interval holds its point estimate."""
    from cellctl.cli import main

    det = ROOT / "models" / "classifier" / "external.detect.pt"
    if not det.is_file():
        pytest.skip("no shipped external detector")
    out = tmp_path / "proof.json"
    rc = main(
        ["detector", "proof", "--surface", "external", "--quick", "--n", "3", "--detector", str(det), "--out", str(out)]
    )
    assert rc == 0
    report = json.loads(out.read_text())
    assert {"shifted", "lofo", "site", "targets", "seeds"} <= report.keys()
    assert report["detector"]["model_id"].startswith("external-detect-")
    assert report["shifted"]["figures"]["false_clean"]["n"] == 3
    assert set(report["lofo"]["families"]) >= {"powder", "soot", "tarnish"}
    assert "10" in report["site"]["enrolled"]
    rates = [r for r in _intervals(report) if r["n"] > 0]
    assert len(rates) > 20
    for r in rates:
        lo, hi = r["ci95"]
        assert lo <= r["rate"] <= hi and r["rate"] <= r["upper95"] <= hi + 1e-9
    # a second slice of the same detector and seed lands in the same file
    main(
        [
            "detector",
            "proof",
            "--surface",
            "external",
            "--quick",
            "--n",
            "3",
            "--only",
            "shifted",
            "--detector",
            str(det),
            "--out",
            str(out),
        ]
    )
    again = json.loads(out.read_text())
    assert again["lofo"] == report["lofo"] and again["shifted"] == report["shifted"]


@pytest.mark.parametrize(("name", "channels"), [("lite1", 24 + 40 + 112), ("lite2", 24 + 48 + 120)])
def test_frozen_backbones_give_multiscale_patches_on_the_stride_8_grid(name: str, channels: int) -> None:
    """The frozen ImageNet Lite1/Lite2 of bank-compare tap strides 4/8/16 onto an S/8 grid, at 128 and 160 px."""
    import torch

    from cellctl.classify.bank_compare import frozen_backbone

    for size in (128, 160):
        f = frozen_backbone(name, size)
        with torch.inference_mode():
            out = f(torch.rand(2, 3, size, size))
        assert out.shape == (2, channels, size // 8, size // 8)
    with pytest.raises(ClassifierError, match="'resnet'"):
        frozen_backbone("resnet", 128)
