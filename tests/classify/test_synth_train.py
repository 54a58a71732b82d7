"""Synthetic data, training outputs, evaluation and inference on a tiny model."""

from __future__ import annotations

import csv
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from cellctl.classify.data import load_image
from cellctl.classify.evaluate import evaluate_folder
from cellctl.classify.infer import SurfaceModel
from cellctl.classify.sample import MIN_VISIBLE_FRACTION, label_from_mask
from cellctl.classify.synth import synth_dataset
from cellctl.errors import ClassifierError


def test_label_rule() -> None:
    m = np.zeros((100, 100), np.float32)
    assert label_from_mask(m) == "clean"
    m[:5, :5] = 1.0  # 0.25 % < 0.3 %: ambiguous
    assert label_from_mask(m) is None
    m[:6, :6] = 1.0  # 0.36 %
    assert label_from_mask(m) == "dirty"
    m2 = np.full((100, 100), 0.4, np.float32)  # faint haze below the opacity rule
    assert label_from_mask(m2) == "clean"
    assert MIN_VISIBLE_FRACTION == 0.003


def test_synth_is_balanced_reproducible_and_labelled(tmp_path: Path) -> None:
    a = synth_dataset(tmp_path / "a", "internal", 12, seed=4, source="procedural", size=48)
    b = synth_dataset(tmp_path / "b", "internal", 12, seed=4, source="procedural", size=48)
    assert a["counts"] == b["counts"] == {"clean": 6, "dirty": 6}
    fa = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*.png"))
    fb = sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*.png"))
    assert fa == fb
    assert (tmp_path / "a" / fa[0]).read_bytes() == (tmp_path / "b" / fb[0]).read_bytes()
    rows = list(csv.DictReader(open(tmp_path / "a" / "internal" / "labels.csv")))
    assert len(rows) == 12
    for r in rows:
        frac = float(r["visible_fraction"])
        assert (r["label"] == "dirty") == (frac >= MIN_VISIBLE_FRACTION)
    with pytest.raises(ClassifierError, match="source 'paint' is unknown"):
        synth_dataset(tmp_path, "internal", 8, source="paint")


def test_training_writes_weights_card_csv_png(tiny_models: Path) -> None:
    pt = tiny_models / "external.pt"
    card = json.loads(pt.with_suffix(".json").read_text())
    assert card["sha256"] == hashlib.sha256(pt.read_bytes()).hexdigest()
    assert card["surface"] == "external" and card["arch"] == "lite0" and card["input_size"] == 64
    assert 0 < card["threshold"] <= 0.5
    assert card["data"]["synth"][0]["source"] == "procedural"
    assert card["backbone"]["sha256"]  # the packaged ImageNet checkpoint, recorded
    rows = list(csv.DictReader(open(pt.with_suffix(".csv"))))
    assert {r["phase"] for r in rows} == {"head", "finetune"}
    assert pt.with_suffix(".png").stat().st_size > 1000
    assert set(card["metrics"]["test"]) >= {"accuracy", "confusion", "false_clean_rate", "roc_auc"}


def test_eval_and_predict(tiny_data: Path, tiny_models: Path, tmp_path: Path) -> None:
    rep = evaluate_folder(tiny_models / "internal.pt", tiny_data, "internal", png=tmp_path / "roc.png")
    assert rep["split"] == "test" and rep["n"] > 0
    assert (tmp_path / "roc.png").is_file()
    rep_all = evaluate_folder(tiny_models / "internal.pt", tiny_data, "internal", split="all")
    assert rep_all["n"] == 48
    m32 = SurfaceModel.load(tiny_models / "internal.pt", surface="internal")
    mf = SurfaceModel.load(tiny_models / "internal.pt", surface="internal", variant="fused")
    imgs = [load_image(p) for p in sorted((tiny_data / "internal").rglob("*.png"))[:6]]
    p1, p2 = m32.predict_proba(imgs), mf.predict_proba(imgs)
    assert np.allclose(p1, p2, atol=1e-4)
    preds = m32.predict(imgs)
    assert all(pr.label in ("clean", "dirty") and 0 <= pr.p_dirty <= 1 for pr in preds)
    assert preds[0].model_id.startswith("internal-lite0-")


def test_load_refuses_wrong_surface_missing_and_foreign_files(tiny_models: Path, tmp_path: Path) -> None:
    with pytest.raises(ClassifierError, match="surface 'external', expected 'internal'"):
        SurfaceModel.load(tiny_models / "external.pt", surface="internal")
    with pytest.raises(ClassifierError, match="do not exist; train them"):
        SurfaceModel.load(tmp_path / "internal.pt", surface="internal")
    import torch

    torch.save({"a": torch.zeros(1)}, tmp_path / "x.pt")
    with pytest.raises(ClassifierError, match="not a cellctl classifier file"):
        SurfaceModel.load(tmp_path / "x.pt")
    # a card that belongs to other weights
    (tmp_path / "m.pt").write_bytes((tiny_models / "external.pt").read_bytes())
    card = json.loads((tiny_models / "external.json").read_text())
    card["sha256"] = "0" * 64
    (tmp_path / "m.json").write_text(json.dumps(card))
    with pytest.raises(ClassifierError, match="do not belong together"):
        SurfaceModel.load(tmp_path / "m.pt")


def test_train_refuses_bad_arguments(tiny_data: Path, tmp_path: Path) -> None:
    from cellctl.classify.train import train

    with pytest.raises(ClassifierError, match="preset 'fast' is unknown"):
        train(tiny_data, "external", tmp_path / "m.pt", preset="fast")
    with pytest.raises(ClassifierError, match="must end in .pt"):
        train(tiny_data, "external", tmp_path / "m.bin")
    with pytest.raises(ClassifierError, match="multiple of 32"):
        train(tiny_data, "external", tmp_path / "m.pt", input_size=100)


def test_twin_source_renders_labelled_views(tmp_path: Path) -> None:
    """The twin's camera renders views of the requested surface; labels follow the mask rule."""
    import cv2

    for surface in ("external", "internal"):
        s = synth_dataset(tmp_path, surface, 6, seed=1, source="twin", size=96)
        assert s["counts"] == {"clean": 3, "dirty": 3}
        rows = list(csv.DictReader(open(tmp_path / surface / "labels.csv")))
        for r in rows:
            assert (r["label"] == "dirty") == (float(r["visible_fraction"]) >= MIN_VISIBLE_FRACTION)
            assert json.loads(r["params"])["bin"]
        img = cv2.imread(str(tmp_path / surface / rows[0]["image"]))
        assert img.shape == (54, 96, 3)  # the D435's 16:9 at 96 px wide


def test_paper_preset_runs_both_phases_live(tiny_data: Path, tmp_path: Path) -> None:
    """Table 4 preset: SGD + StepLR head phase, then all layers on live images."""
    from cellctl.classify.train import train

    card = train(tiny_data, "internal", tmp_path / "p.pt", preset="paper", input_size=64, max_epochs=(2, 1), threads=2)
    assert card["phases"]["head"]["optimizer"] == "sgd" and card["phases"]["head"]["lr_step"] == 5
    assert card["phases"]["finetune"]["unfreeze"] == 1.0 and not card["phases"]["finetune"]["cached"]
    assert card["phases"]["head"]["cached"] is True  # phase 1 always trains on cached features
    rows = list(csv.DictReader(open(tmp_path / "p.csv")))
    assert [r["phase"] for r in rows] == ["head", "head", "finetune"]
    assert float(rows[2]["lr"]) == 1e-4


def test_the_card_records_what_each_phase_trained_on(tiny_models: Path) -> None:
    """Default preset: the head on cached pooled features, the fine-tune on cached prefix activations."""
    card = json.loads((tiny_models / "external.json").read_text())
    assert card["preset"] == "default"
    assert card["phases"]["head"]["cached"] is True
    assert card["phases"]["finetune"]["cached"] is True
    assert card["best_epoch"]["phase"] in ("head", "finetune") and card["best_epoch"]["global_epoch"] >= 1


def test_recalibrate_refits_threshold_and_keeps_card_and_weights_together(
    tiny_data: Path, tiny_models: Path, tmp_path: Path
) -> None:
    """``cellctl eval --recalibrate``: a new target moves the threshold; card and weights still match."""
    from cellctl.classify.calibration import calibrate

    for ext in (".pt", ".json"):
        (tmp_path / f"m{ext}").write_bytes((tiny_models / f"external{ext}").read_bytes())
    before = json.loads((tmp_path / "m.json").read_text())
    card = calibrate(tmp_path / "m.pt", tiny_data, target_false_clean=0.2, threads=2)
    assert card["decision"]["target_false_clean"] == 0.2 and "calibrated" in card
    assert card["sha256"] == hashlib.sha256((tmp_path / "m.pt").read_bytes()).hexdigest() != before["sha256"]
    assert json.loads((tmp_path / "m.json").read_text()) == card
    model = SurfaceModel.load(tmp_path / "m.pt", surface="external")  # refuses a card of other weights
    assert model.threshold == card["threshold"] and model.temperature == card["temperature"]
    with pytest.raises(ClassifierError, match="was trained on"):
        calibrate(tmp_path / "m.pt", tmp_path, threads=2)
