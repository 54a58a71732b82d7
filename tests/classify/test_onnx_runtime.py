"""ONNX Runtime for the detector: export, parity with PyTorch, freshness, runtime choice."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from cellctl.classify import onnx_export as ox
from cellctl.classify import runtime as rt
from cellctl.classify.fusion import Detector, detector_path
from cellctl.config import ClassifierConfig
from cellctl.errors import ClassifierError
from cellctl.hashing import file_sha256

MODELS = Path(__file__).resolve().parents[2] / "models" / "classifier"


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The shipped external detector copied to a temp folder and exported there."""
    src = detector_path(MODELS, "external")
    if not src.is_file():
        pytest.skip("no shipped external detector")
    d = tmp_path_factory.mktemp("onnx")
    for f in (src, src.with_suffix(".json")):
        shutil.copy(f, d / f.name)
    ox.export_detector(d / src.name)
    return d / src.name


def test_ort_and_torch_agree_on_a_fixed_batch_and_label_alike(exported: Path) -> None:
    """Maps within PARITY_ATOL and identical labels on clean and dirty images of both surfaces'
    steel: an export can never silently change a decision."""
    ref = Detector.load(exported, runtime="torch")
    ort = Detector.load(exported, runtime="onnx")
    assert ref.engine is None and isinstance(ort.engine, rt.OnnxMaps)
    for surface, seed in (("external", 1), ("internal", 2)):
        images = ox.parity_images(surface, 12, seed=seed, size=160)
        par = ox.parity(ref, ort, images)
        assert par["max_abs_logit"] <= rt.PARITY_ATOL and par["max_abs_distance"] <= rt.PARITY_ATOL, par
        assert par["labels_differ"] == 0, par
        a, b = ref.predict(images, batch=5), ort.predict(images, batch=5)
        assert [d.label for d in a] == [d.label for d in b]
        assert [d.uncertain for d in a] == [d.uncertain for d in b]
        assert np.allclose([d.p_dirty for d in a], [d.p_dirty for d in b], atol=rt.PARITY_ATOL)
        assert np.abs(np.stack([d.heat for d in a]) - np.stack([d.heat for d in b])).max() <= rt.PARITY_ATOL
    labels = {d.label for d in ort.predict(ox.parity_images("external", 12, seed=1, size=160))}
    assert labels == {"clean", "dirty"}  # the fixed set exercises both decisions


def test_export_is_recorded_in_the_card_and_auto_uses_it(exported: Path) -> None:
    card = json.loads(exported.with_suffix(".json").read_text())
    onnx_file = rt.onnx_path(exported)
    assert onnx_file.name == "external.detect.onnx"
    assert card["onnx"]["sha256"] == file_sha256(onnx_file)
    assert card["onnx"]["source_sha256"] == file_sha256(exported) == card["sha256"]
    assert card["onnx"]["parity"]["labels_differ"] == 0
    det = Detector.load(exported, threads=2)
    assert det.engine.describe()["intra_op_threads"] == 2
    assert det.engine.describe()["sha256"] == card["onnx"]["sha256"]


def _with_networks_changed(exported: Path, out: Path) -> Path:
    blob = torch.load(exported, weights_only=True)
    blob["head"] = {k: v + 0.01 for k, v in blob["head"].items()}
    out.mkdir(parents=True, exist_ok=True)
    torch.save(blob, out / exported.name)
    shutil.copy(rt.onnx_path(exported), out / rt.onnx_path(exported).name)
    return out / exported.name


def test_a_stale_export_is_refused_with_the_command_that_fixes_it(exported: Path, tmp_path: Path) -> None:
    stale = _with_networks_changed(exported, tmp_path / "retrained")
    for runtime in ("auto", "onnx"):
        with pytest.raises(ClassifierError, match=r"stale.*cellctl detector export --surface external"):
            Detector.load(stale, runtime=runtime)
    assert Detector.load(stale, runtime="torch").engine is None


def test_runtime_choice_without_an_export(exported: Path, tmp_path: Path) -> None:
    lone = tmp_path / exported.name
    shutil.copy(exported, lone)
    assert Detector.load(lone).engine is None  # auto: PyTorch when there is no export
    with pytest.raises(ClassifierError, match="no ONNX export"):
        Detector.load(lone, runtime="onnx")
    with pytest.raises(ClassifierError, match="'tensorrt' is unknown"):
        Detector.load(lone, runtime="tensorrt")
    assert ClassifierConfig().runtime == "auto"
    with pytest.raises(ValueError):
        ClassifierConfig(runtime="tensorrt")


def test_a_file_with_another_bank_shares_the_export_and_searches_its_own_bank(exported: Path, tmp_path: Path) -> None:
    """The bank is an input of the exported graph: a file with the same networks and another bank (as
    site enrollment writes) runs on the shipped export, and its distances are its own bank's."""
    blob = torch.load(exported, weights_only=True)
    blob["bank"] = blob["bank"][:300] * 0.5
    site = tmp_path / "site.pt"
    torch.save(blob, site)
    also = (rt.onnx_path(exported),)
    ort = Detector.load(site, runtime="onnx", also_onnx=also)
    ref = Detector.load(site, runtime="torch")
    base = Detector.load(exported, runtime="onnx")
    images = ox.parity_images("external", 4, seed=3, size=128)
    assert ox.parity(ref, ort, images)["max_abs_distance"] <= rt.PARITY_ATOL
    assert ox.parity(base, ort, images)["max_abs_distance"] > 0.1
    other = tmp_path / "other"
    stale = _with_networks_changed(exported, other)
    stale.with_name("external.detect.onnx").unlink()
    assert Detector.load(stale, also_onnx=also).engine is None  # another file's export that does not fit: skipped


def test_an_export_that_disagrees_is_not_written(
    exported: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    src = tmp_path / exported.name
    shutil.copy(exported, src)
    monkeypatch.setattr(ox, "PARITY_ATOL", 0.0)
    with pytest.raises(ClassifierError, match="disagrees with PyTorch"):
        ox.export_detector(src)
    assert not rt.onnx_path(src).exists() and not list(tmp_path.glob("*.tmp"))


@pytest.mark.parametrize("surface", ["external", "internal"])
def test_shipped_exports_fit_their_detectors(surface: str) -> None:
    """What models/classifier ships is fresh: ``runtime: onnx`` loads it, and the card names its hash."""
    pt = detector_path(MODELS, surface)
    if not rt.onnx_path(pt).is_file():
        pytest.skip(f"no shipped {surface} export")
    det = Detector.load(pt, surface=surface, runtime="onnx")
    card = json.loads(pt.with_suffix(".json").read_text())
    assert card["onnx"]["sha256"] == det.engine.sha256 == file_sha256(rt.onnx_path(pt))


def test_classify_cli_runs_either_runtime_with_the_same_answer(exported: Path, tmp_path: Path, capsys) -> None:
    """``classifier.runtime`` reaches ``cellctl classify``; a missing detector to export fails in one line."""
    import cv2

    from cellctl.cli import main

    img = tmp_path / "v.png"
    cv2.imwrite(str(img), cv2.cvtColor(ox.parity_images("external", 2, seed=9, size=128)[1], cv2.COLOR_RGB2BGR))
    lines = {}
    for runtime in ("onnx", "torch"):
        rc = main(
            ["classify", str(img), "--surface", "external", "--detector", str(exported), "--json"]
            + ["--set", f"classifier.runtime={runtime}"]
        )
        assert rc == 0
        (lines[runtime],) = [json.loads(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]
    assert lines["onnx"]["label"] == lines["torch"]["label"]
    assert abs(lines["onnx"]["p_dirty"] - lines["torch"]["p_dirty"]) <= rt.PARITY_ATOL
    rc = main(["detector", "export", "--surface", "external", "--model", str(tmp_path / "none.detect.pt")])
    assert rc != 0 and not list(tmp_path.glob("*.onnx"))


def test_the_worker_names_what_runs_each_detector(exported: Path) -> None:
    """The classifier worker's ``models`` op says whether ORT (which export, threads) or PyTorch runs a detector."""
    from cellctl.workers.classifier import ClassifierService

    svc = ClassifierService.__new__(ClassifierService)  # describe() only: no supervised models to load
    svc.detectors = {
        "external": Detector.load(exported, runtime="onnx", threads=1),
        "internal": Detector.load(exported, runtime="torch"),
    }
    svc.models, svc.problems, svc.decision = {}, {}, "detector"
    svc.paths = {s: exported for s in svc.detectors}
    got = svc.describe().models
    assert got["external"].runtime["runtime"] == "onnx" and got["external"].runtime["intra_op_threads"] == 1
    assert got["external"].runtime["sha256"] == file_sha256(rt.onnx_path(exported))
    assert got["internal"].runtime == {"runtime": "torch"}
