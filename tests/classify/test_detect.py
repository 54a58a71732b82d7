"""The contamination synthesiser, the held-out generator, the detector and the heat-map geometry."""

from __future__ import annotations

import hashlib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from cellctl.classify.contamination import FAMILIES, Optics, closeup_steel, composite, draw_family, optics, visible_mask
from cellctl.classify.heatmap import (
    FaceFusion,
    ViewEvidence,
    decode_heat,
    encode_heat,
    face_probabilities,
    fuse_views,
    project_heat,
    relook_pose,
    verdict,
)
from cellctl.classify.shifted import HELD_OUT_FAMILIES
from cellctl.errors import ClassifierError


def test_every_family_draws_contamination_that_changes_the_image_only_where_it_lies() -> None:
    rng = np.random.default_rng(0)
    base = closeup_steel("external", 96, 128, rng)
    for name in FAMILIES:
        layer = draw_family(name, 96, 128, rng)
        assert layer.alpha.shape == (96, 128) and 0 <= layer.alpha.min() and layer.alpha.max() <= 1, name
        img, alpha = composite(base, layer)
        far = alpha == 0
        assert np.allclose(img[far], base[far], atol=1e-6) or layer.mode == "film", name
        assert np.abs(img - base).max() > 0.02, name


def test_dark_training_families_darken_the_steel_and_tarnish_keeps_its_texture() -> None:
    """soot covers the steel with a dark matte layer; tarnish multiplies it by a transmission < 1,
    so the brushed texture under it survives (scaled), unlike a covering layer."""
    rng = np.random.default_rng(4)
    base = closeup_steel("external", 96, 128, rng)
    for name in ("soot", "tarnish"):
        layer = draw_family(name, 96, 128, rng)
        img, alpha = composite(base, layer)
        core = alpha > 0.5 * alpha.max()
        assert core.sum() > 20, name
        assert img[core].mean() < 0.85 * base[core].mean(), name
    layer = draw_family("tarnish", 96, 128, np.random.default_rng(5))
    full = type(layer)(np.ones_like(layer.alpha), layer.rgb, layer.mode, layer.family, layer.params)
    img, _ = composite(base, full)
    assert np.allclose(img, base * layer.rgb, atol=1e-6)
    assert 0.3 < img.std() / base.std() / float(layer.rgb.mean()) < 1.2


def test_composite_respects_the_surface_pixels() -> None:
    rng = np.random.default_rng(1)
    base = closeup_steel("internal", 64, 64, rng)
    where = np.zeros((64, 64), bool)
    where[:, :32] = True
    _, alpha = composite(base, draw_family("powder", 64, 64, rng), where)
    assert alpha[:, 32:].max() == 0


def test_visible_mask_needs_contrast_after_the_optics() -> None:
    rng = np.random.default_rng(2)
    base = closeup_steel("external", 64, 64, rng)
    layer = draw_family("powder", 64, 64, rng)
    dirty, alpha = composite(base, layer)
    o = Optics(noise_sigma=2.0, noise_seed=5)
    vis = visible_mask(optics(dirty, o), optics(base, o), alpha)
    assert vis.sum() > 0
    assert not vis[alpha < 0.1].any()
    assert visible_mask(optics(base, o), optics(base, o), alpha).sum() == 0  # same image: nothing visible


def _flat(level: int, size: int = 64) -> np.ndarray:
    return np.full((size, size, 3), level, np.uint8)


def test_visible_mask_counts_a_patch_colour_change_from_min_delta_e() -> None:
    alpha = np.ones((64, 64), np.float32)
    # mid grey: 3 grey levels are ~1.2 L* (below MIN_DELTA_E), 20 levels ~7.6 L* (above)
    assert visible_mask(_flat(123), _flat(120), alpha).sum() == 0
    assert visible_mask(_flat(140), _flat(120), alpha).all()
    tinted = _flat(120).copy()
    tinted[..., 0] += 12  # a reddish cast at the same brightness class: a colour difference
    assert visible_mask(tinted, _flat(120), alpha).all()


def test_visible_mask_ignores_scattered_pixel_changes_but_sees_vanished_texture() -> None:
    rng = np.random.default_rng(4)
    alpha = np.ones((64, 64), np.float32)
    clean = _flat(120)
    speckled = clean.copy()
    speckled[::6, ::6] += 25  # single grain-line pixels moved by 25 grey levels: the picture looks the same
    assert np.abs(speckled.astype(int) - clean.astype(int)).max() >= 12  # the old per-pixel rule said dirty
    assert visible_mask(speckled, clean, alpha).sum() == 0
    # strong texture (RMS ~ 10 L*) wiped flat at the same mean: a haze
    grain = np.clip(120 + rng.normal(0, 25, (64, 64, 1)), 0, 255).astype(np.uint8).repeat(3, axis=2)
    assert visible_mask(np.full_like(grain, int(grain.mean())), grain, alpha)[8:-8, 8:-8].all()
    # a veil that takes 40 % of that grain's contrast (> 3 L*) is not visible: Weber, not a fixed step
    m = float(grain.mean())
    veiled = np.clip(m + 0.6 * (grain.astype(np.float32) - m), 0, 255).astype(np.uint8)
    assert visible_mask(veiled, grain, alpha).mean() < 0.01
    # ...and nothing where the contamination does not lie, however the image changed
    assert visible_mask(_flat(200), clean, np.zeros((64, 64), np.float32)).sum() == 0


def _reflections(size: int = 64) -> np.ndarray:
    """Polished-steel-like clean image: bright steel (L* ~ 78) with dark reflection bands (L* ~ 22)."""
    img = np.full((size, size, 3), 200, np.uint8)
    for x0 in range(0, size, 8):
        img[:, x0 : x0 + 4] = 35
    return img


def test_visible_mask_judges_a_change_against_the_variation_around_it() -> None:
    size = 64
    alpha = np.zeros((size, size), np.float32)
    alpha[24:40, 24:40] = 0.5  # a film over the middle
    lifted_cluttered = _reflections(size)
    lifted_cluttered[24:40, 24:40] = np.maximum(lifted_cluttered[24:40, 24:40], 55)  # dark bands lifted 35 -> 55
    # against the twin alone the lift is visible (~8 L* on the dark bands)...
    assert visible_mask(lifted_cluttered, _reflections(size), alpha, clutter_k=0).sum() > 0
    # ...but the bands around it vary far more than that: in the image it is more of the same steel
    assert visible_mask(lifted_cluttered, _reflections(size), alpha).sum() == 0
    # the same lift on an even surface stands out from its surroundings
    flat = np.full((size, size, 3), 35, np.uint8)
    lifted_flat = flat.copy()
    lifted_flat[24:40, 24:40] = 55
    assert visible_mask(lifted_flat, flat, alpha)[28:36, 28:36].all()
    # white powder on the cluttered steel is far above its variation: still visible
    powder = _reflections(size)
    powder[24:40, 24:40] = 250
    assert visible_mask(powder, _reflections(size), alpha)[28:36, 28:36].all()
    with pytest.raises(ClassifierError, match="clutter_k"):
        visible_mask(flat, flat, alpha, clutter_k=-1)


def test_local_variation_counts_only_the_weighted_surroundings() -> None:
    from cellctl.classify.contamination import local_variation

    v = np.zeros((32, 32), np.float32)
    v[:, ::2] = 10.0  # stripes: RMS deviation 5 everywhere
    assert np.allclose(local_variation(v, np.ones_like(v))[8:-8, 8:-8], 5.0, atol=0.3)
    w = np.ones_like(v)
    w[:, 16:] = 0  # the right half does not count...
    v2 = v.copy()
    v2[:, 16:] = 1000.0  # ...so its values do not raise the variation
    assert local_variation(v2, w)[8:-8, 4:12].max() < 5.5
    assert local_variation(v, np.zeros_like(v)).max() == 0  # nothing to compare with


def test_held_out_families_are_not_training_families() -> None:
    assert not set(HELD_OUT_FAMILIES) & set(FAMILIES)
    with pytest.raises(ClassifierError, match="unknown"):
        draw_family("splatter", 8, 8, np.random.default_rng(0))


def _digest(folder: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*.png")):
        h.update(p.name.encode() + p.read_bytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def contam(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from cellctl.classify.contam_dataset import contam_dataset

    root = tmp_path_factory.mktemp("contam")
    for s in ("external", "internal"):
        contam_dataset(root / "train", s, 48, seed=3, source="closeup", size=96)
    contam_dataset(root / "shifted", "external", 16, seed=9, shifted=True, source="closeup", size=96)
    return root


def test_contam_dataset_is_seeded_labelled_and_has_masks(contam: Path, tmp_path: Path) -> None:
    import csv
    import json

    from cellctl.classify.contam_dataset import contam_dataset

    base = contam / "train" / "external"
    dirty = sorted((base / "dirty").glob("*.png"))
    assert len(dirty) == 24 and len(list((base / "clean").glob("*.png"))) == 24
    assert {p.name for p in (base / "masks").glob("*.png")} == {p.name for p in dirty}
    rows = list(csv.DictReader(open(base / "labels.csv")))
    assert {r["family"] for r in rows if r["label"] == "dirty"} <= {
        "+".join((a, b)) for a in FAMILIES for b in FAMILIES
    } | set(FAMILIES)
    prov = json.loads((base / "synth.json").read_text())[-1]
    assert prov["seed"] == 3 and prov["generator"] == "cellctl-contam/3"
    again = contam_dataset(tmp_path, "external", 48, seed=3, source="closeup", size=96)
    assert again["counts"] == prov["counts"]
    assert _digest(tmp_path / "external" / "dirty") == _digest(base / "dirty")
    shifted = list(csv.DictReader(open(contam / "shifted" / "external" / "labels.csv")))
    fams = {f for r in shifted if r["label"] == "dirty" for f in r["family"].split("+")}
    assert fams and fams <= set(HELD_OUT_FAMILIES)


def test_detector_trains_predicts_and_reloads(contam: Path, tmp_path: Path) -> None:
    from cellctl.classify.fusion import Detector, evaluate_detector, train_detector

    out = tmp_path / "external.detect.pt"
    card = train_detector(contam / "train", "external", out, epochs=2, bank_size=64)
    assert card["sha256"] and card["metrics"]["test"]["n"] > 0
    assert not Path(card["data"]["root"]).is_absolute() or card["data"]["root"] == str(contam / "train")
    # the card says how to make its data again (a clean checkout has no data/)
    assert card["data"]["recreate"] == [
        f"cellctl dataset contam --surface external --n 48 --out {card['data']['root']} --seed 3"
        " --source closeup --size 96"
    ]
    det = Detector.load(out, surface="external")
    from cellctl.classify.data import load_image

    img = load_image(next((contam / "train" / "external" / "dirty").glob("*.png")))
    d = det.predict([img])[0]
    assert d.label in ("clean", "dirty") and d.heat.shape == (16, 16)
    assert 0.0 <= d.p_dirty <= 1.0 and 0.0 <= d.p_supervised <= 1.0
    assert set(d.as_dict()) >= {"label", "p_dirty", "uncertain", "model_id", "p_supervised", "anomaly_z"}
    rep = evaluate_detector(det, contam / "shifted", "external")
    assert rep["n"] == 16 and set(rep["by_family"]) - {"none"} <= set(HELD_OUT_FAMILIES) | {
        f"{a}+{b}" for a in HELD_OUT_FAMILIES for b in HELD_OUT_FAMILIES
    }
    import torch

    blob = torch.load(out, weights_only=True)
    assert blob["format"] == "cellctl-detector/2" and blob["backbone"]
    old = {**blob, "format": "cellctl-detector/1"}
    del old["backbone"]
    torch.save(old, tmp_path / "old.detect.pt")
    assert Detector.load(tmp_path / "old.detect.pt").predict([img])[0].heat.shape == (16, 16)
    with pytest.raises(ClassifierError, match="expected 'internal'|for 'external'"):
        Detector.load(out, surface="internal")
    # continuing from it: 0 epochs keep its backbone and head exactly, bank and threshold refitted
    cont = tmp_path / "cont" / "external.detect.pt"
    card2 = train_detector(contam / "train", "external", cont, epochs=0, bank_size=64, init_from=out)
    assert card2["init_from"]["sha256"] == card["sha256"] and "--init-from" in card2["command"]
    b2 = torch.load(cont, weights_only=True)
    assert all(torch.equal(b2["backbone"][k], blob["backbone"][k]) for k in blob["backbone"])
    assert all(torch.equal(b2["head"][k], blob["head"][k]) for k in blob["head"])
    # a calibration draw of the training generator joins val for fusion and threshold; shifted draws cannot
    from cellctl.classify.contam_dataset import contam_dataset

    contam_dataset(tmp_path / "calib", "external", 24, seed=5, source="closeup", size=96)
    card3 = train_detector(
        contam / "train",
        "external",
        tmp_path / "c" / "external.detect.pt",
        epochs=0,
        bank_size=64,
        init_from=out,
        calib=tmp_path / "calib",
    )
    assert card3["data"]["calib"]["n"] == 24 and card3["data"]["calib"]["dirty"] == 12
    assert card3["metrics"]["calib_pool"]["n"] == card3["metrics"]["val"]["n"] + 24 and "--calib" in card3["command"]
    assert card3["data"]["calib"]["recreate"][0].startswith("cellctl dataset contam --surface external --n 24")
    assert card3["decision"]["score"] in ("fused", "supervised")
    assert set(card3["decision"]["pool_accuracy"]) == {"fused", "supervised"}
    # the decision score: "supervised" answers with the head's own calibrated probability
    det.decision_score = "supervised"
    d_sup = det.predict([img])[0]
    assert d_sup.p_dirty == d_sup.p_supervised and np.array_equal(d_sup.heat, d.heat)
    torch.save({**blob, "decision_score": "median"}, tmp_path / "bad.detect.pt")
    with pytest.raises(ClassifierError, match="decision_score"):
        Detector.load(tmp_path / "bad.detect.pt")
    with pytest.raises(ClassifierError, match="shifted"):
        train_detector(
            contam / "train", "external", tmp_path / "z.detect.pt", epochs=0, init_from=out, calib=contam / "shifted"
        )
    with pytest.raises(ClassifierError, match="needs a backbone"):
        train_detector(
            contam / "train", "external", tmp_path / "x.detect.pt", epochs=0, init_from=tmp_path / "old.detect.pt"
        )
    with pytest.raises(ClassifierError, match="expected 'internal'"):
        train_detector(contam / "train", "internal", tmp_path / "y.detect.pt", epochs=0, init_from=out)
    card_path = out.with_suffix(".json")
    card_path.write_text(card_path.read_text().replace(card["sha256"], "0" * 64))
    with pytest.raises(ClassifierError, match="other weights"):
        Detector.load(out)


def test_memory_bank_scores_a_foreign_patch_far_from_clean_ones() -> None:
    import torch

    from cellctl.classify.anomaly import MemoryBank

    g = torch.Generator().manual_seed(0)
    clean = torch.randn(20, 8, 4, 4, generator=g) * 0.1
    bank = MemoryBank.fit(clean, 32)
    q = bank.standardise(clean[:2].clone())
    near = bank(q).max().item()
    q[0, :, 1, 1] += 10.0
    assert bank(q)[0, 1, 1].item() > 5 * max(near, 1e-3)


def test_augmentation_moves_the_patch_labels_with_the_image() -> None:
    import torch

    from cellctl.classify.anomaly import GRID, INPUT_SIZE
    from cellctl.classify.finetune import augment_batch

    cell = INPUT_SIZE // GRID
    x = torch.full((8, 3, INPUT_SIZE, INPUT_SIZE), 60, dtype=torch.uint8)
    x[:, :, 2 * cell : 3 * cell, 11 * cell : 12 * cell] = 250  # one bright patch at row 2, column 11
    m = torch.zeros(8, GRID, GRID)
    m[:, 2, 11] = 1.0
    xa, ma = augment_batch(x, m, torch.Generator().manual_seed(1))
    assert xa.dtype == torch.float32 and 0.0 <= float(xa.min()) and float(xa.max()) <= 1.0
    flipped = 0
    for k in range(8):
        bright = xa[k].mean(0).unfold(0, cell, cell).unfold(1, cell, cell).mean((-1, -2))
        assert ma[k].sum() == 1 and bright.argmax() == ma[k].argmax()
        flipped += int(ma[k].argmax() != 2 * GRID + 11)
    assert flipped > 0  # some images were flipped, and their labels with them


def test_fine_tuning_learns_to_find_a_spot_and_the_file_carries_its_backbone(tmp_path: Path) -> None:
    """A few epochs on images where dirty = a small dark spot: the largest patch logit separates
    the classes on held-back images; the ImageNet backbone weights moved."""
    import torch

    from cellctl.classify.anomaly import GRID, INPUT_SIZE, PatchFeatures
    from cellctl.classify.evaluate import roc_auc
    from cellctl.classify.finetune import finetune
    from cellctl.classify.fusion import _head

    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    cell = INPUT_SIZE // GRID

    def draw(n: int) -> tuple[torch.Tensor, np.ndarray, np.ndarray]:
        x = np.clip(rng.normal(150, 12, (n, 3, INPUT_SIZE, INPUT_SIZE)), 0, 255).astype(np.uint8)
        m = np.zeros((n, GRID, GRID), np.float32)
        y = np.arange(n) % 2
        for k in np.flatnonzero(y):
            r, c = rng.integers(1, GRID - 1, 2)
            x[k, :, r * cell : (r + 1) * cell, c * cell : (c + 1) * cell] = 40
            m[k, r, c] = 1.0
        return torch.from_numpy(x), m, y

    xtr, mtr, ytr = draw(64)
    feats, head = PatchFeatures(), _head()
    before = {k: v.clone() for k, v in feats.state_dict().items()}
    finetune(feats, head, xtr, mtr, ytr, epochs=3, seed=0)
    moved = [k for k, v in feats.state_dict().items() if v.dtype.is_floating_point and not torch.equal(v, before[k])]
    assert moved and not any("running" in k for k in moved)  # weights learn, batch-norm statistics stay
    xte, _, yte = draw(32)
    with torch.inference_mode():
        z = head(feats(xte.float() / 255.0))[:, 0].flatten(1).max(1).values.numpy()
    assert roc_auc(z, yte) > 0.9


def test_heat_roundtrip_and_bad_input() -> None:
    h = np.linspace(0, 1, 256).reshape(16, 16)
    assert np.abs(decode_heat(encode_heat(h), 16) - h).max() <= 0.5 / 255 + 1e-9
    with pytest.raises(ClassifierError, match="256 values, expected 8x8"):
        decode_heat(encode_heat(h), 8)
    with pytest.raises(ClassifierError, match="base64"):
        decode_heat("not base64!", 16)


def _square_mesh() -> SimpleNamespace:
    """Two triangles: the left (x<0) and the right (x>0) half of a 0.4 m square at z=0."""
    v = np.array([[-0.2, -0.2, 0], [0.0, -0.2, 0], [0.0, 0.2, 0], [-0.2, 0.2, 0], [0.2, -0.2, 0], [0.2, 0.2, 0]], float)
    f = np.array([[0, 1, 2], [1, 4, 5]])
    return SimpleNamespace(vertices=v, faces=f, n_faces=2, areas=np.array([0.04, 0.04]), surface=np.zeros(2, int))


def _camera_above() -> tuple[np.ndarray, SimpleNamespace]:
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # optical +Z down onto the square, image x = bin x
    T[2, 3] = 0.5
    intr = SimpleNamespace(fx=400.0, fy=400.0, cx=160.0, cy=90.0, width=320, height=180)
    return T, intr


def test_heat_projects_onto_the_face_it_covers() -> None:
    mesh = _square_mesh()
    T, intr = _camera_above()
    heat = np.zeros((16, 16))
    heat[:, :8] = 0.95  # left half of the image is dirty
    faces, p = project_heat(heat, T, intr, mesh, [0, 1])
    got = dict(zip(faces.tolist(), p.tolist(), strict=True))
    assert got[0] > 0.9 and got[1] < 0.5


def test_a_spot_in_a_corner_of_a_large_face_reaches_it_through_the_sample_grid() -> None:
    mesh = _square_mesh()
    T, intr = _camera_above()
    # face 0 is the triangle (-0.2,-0.2) (0,-0.2) (0,0.2); the image sees y within ±0.11 m. Hot: the
    # patches around its grid point (-0.15, -0.1) (columns 1-2, rows 14-15), far from its inner samples
    heat = np.zeros((16, 16))
    heat[14:16, 1:3] = 0.95
    _, p4 = project_heat(heat, T, intr, mesh, [0])
    assert p4[0] < 0.5  # the four inner samples miss it
    _, pg = project_heat(heat, T, intr, mesh, [0], subdiv=4)
    assert pg[0] > 0.5


def test_clean_weight_keeps_one_view_that_saw_a_spot_from_being_cancelled() -> None:
    mesh = _square_mesh()
    T, intr = _camera_above()
    hot, cold = np.full((16, 16), 0.99), np.full((16, 16), 0.1)
    views = [ViewEvidence(np.array([0]), T, hot, 0.99)] + [ViewEvidence(np.array([0]), T, cold, 0.1)] * 2
    assert not fuse_views(views, mesh, intr).dirty[0]
    assert fuse_views(views, mesh, intr, clean_weight=0.25).dirty[0]
    with pytest.raises(ClassifierError, match="clean_weight"):
        FaceFusion(2, clean_weight=0.0)


def test_face_fusion_needs_agreeing_views_and_keeps_unseen_faces_at_the_prior() -> None:
    mesh = _square_mesh()
    T, intr = _camera_above()
    hot = np.zeros((16, 16))
    hot[:, :8] = 0.97
    one = fuse_views([ViewEvidence(np.array([0]), T, hot * 0 + 0.6, 0.6)], mesh, intr)
    assert one.p[0] < 0.5  # one mildly positive view does not outweigh the prior
    many = fuse_views([ViewEvidence(np.array([0, 1]), T, hot, 0.97)] * 3, mesh, intr)
    assert many.dirty.tolist() == [True, False] and many.dirty_area_m2 == pytest.approx(0.04)
    unseen = fuse_views([ViewEvidence(np.array([0]), T, hot, 0.97)], mesh, intr)
    assert not unseen.seen[1]
    js = many.as_json()
    p = face_probabilities(js, 2)
    assert p is not None and p[0] > 0.9 and p[1] < 0.1
    assert np.isnan(face_probabilities(unseen.as_json(), 2)[1])
    assert verdict(many, ["clean"], "faces") == "dirty" and verdict(many, ["clean"], "views") == "clean"
    assert verdict(many, [], "faces", min_dirty_area_cm2=500.0) == "clean"
    with pytest.raises(ClassifierError, match="rule"):
        verdict(many, [], "majority")
    with pytest.raises(ClassifierError, match="prior"):
        FaceFusion(2, prior=0.0)


def test_relook_pose_keeps_the_point_in_view_from_another_angle() -> None:
    T, _ = _camera_above()
    for k in range(4):
        R = relook_pose(T, k, offset_m=0.0, glance_deg=12.0, depth=0.5)
        pivot = T[:3, 3] + 0.5 * T[:3, 2]
        ahead = R[:3, 3] + 0.5 * R[:3, 2]
        assert np.allclose(ahead, pivot, atol=1e-9)
        angle = np.degrees(np.arccos(np.clip(R[:3, 2] @ T[:3, 2], -1, 1)))
        assert angle == pytest.approx(12.0, abs=1e-6)
        assert np.allclose(R[:3, :3] @ R[:3, :3].T, np.eye(3), atol=1e-9)
    shifted = relook_pose(T, 0, offset_m=0.03, glance_deg=0.0, depth=0.5)
    assert np.linalg.norm(shifted[:3, 3] - T[:3, 3]) == pytest.approx(0.03)


def test_worker_and_cli_answer_with_the_detector(contam: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A models folder with ``external.detect.pt``: the worker's reply carries the heat map and the
    two part scores; ``cellctl classify --json`` keeps one object per file with ``label``."""
    import json
    import shutil

    from cellctl.classify.fusion import train_detector
    from cellctl.classify.heatmap import decode_heat
    from cellctl.cli import main
    from cellctl.messages import ClassifyRequest
    from cellctl.workers.classifier import ClassifierService

    models = tmp_path / "models"
    train_detector(contam / "train", "external", models / "external.detect.pt", epochs=1, bank_size=32)
    img = next((contam / "train" / "external" / "dirty").glob("*.png"))
    svc = ClassifierService(models, variant="fp32", threads=1)
    (reply,) = svc.classify([(ClassifyRequest(surface="external", format="png"), img.read_bytes())])
    assert reply.model_id.startswith("external-detect-") and reply.p_supervised is not None
    assert decode_heat(reply.heatmap, reply.heat_grid).shape == (16, 16)
    (refused,) = svc.classify([(ClassifyRequest(surface="internal", format="png"), img.read_bytes())])
    assert "no model for surface 'internal'" in str(refused)
    shutil.copy(img, tmp_path / "a.png")
    rc = main(
        [
            "classify",
            str(tmp_path / "a.png"),
            "--surface",
            "external",
            "--json",
            "--set",
            f"classifier.models_dir={models}",
        ]
    )
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]
    assert rc == 0 and len(lines) == 1
    assert lines[0]["image"].endswith("a.png") and lines[0]["label"] in ("clean", "dirty")
    assert {"p_dirty", "uncertain", "model_id", "p_supervised", "anomaly_z"} <= set(lines[0])


def test_bench_inspect_scores_collected_cycles_against_the_truth() -> None:
    from cellctl.bench.classify.inspect import score_cycles
    from cellctl.config import VerdictConfig

    mesh = _square_mesh()
    T, intr = _camera_above()
    hot = np.zeros((16, 16))
    hot[:, :8] = 0.99
    cold = np.full((16, 16), 0.01)

    def cycle(kind: str, heat: np.ndarray, gt: list[bool]) -> dict:
        views = [ViewEvidence(np.array([0, 1]), T, heat, float(heat.max()))] * 2
        return {
            "surface": "external",
            "kind": kind,
            "gt": np.array(gt),
            "seen_plan": np.array([0, 1]),
            "views": views,
            "labels": ["dirty" if heat.max() > 0.5 else "clean"] * 2,
            "uncertain": 0,
            "relooks": 0,
            "hottest": None,
        }

    run = {
        "cycles": [
            cycle("clean", cold, [False, False]),
            cycle("one_spot", hot, [True, False]),  # found
            cycle("one_spot", cold, [False, True]),  # missed: a false clean
            cycle("clean", hot, [False, False]),  # a false dirty
        ],
        "mesh": mesh,
        "intrinsics": intr,
        "latency_ms": [5.0, 7.0],
        "relook": {},
        "setup": {},
    }
    rep = score_cycles(run, VerdictConfig(rule="faces"))
    assert (rep["false_clean_bins"], rep["dirty_seen_bins"]) == (1, 2)
    assert (rep["false_dirty_bins"], rep["clean_bins"]) == (1, 2)
    assert rep["face_recall"] == pytest.approx(0.5) and rep["face_precision"] == pytest.approx(0.5)
    assert rep["any_view_rule"]["false_dirty_bins"] == 1 and rep["cycles"] == 4


def test_label_check_scores_every_candidate_factor_from_the_cli(tmp_path) -> None:
    import json

    from cellctl.classify.label_check import CANDIDATES
    from cellctl.cli import main

    out = tmp_path / "lc.json"
    assert (
        main(
            ["detector", "label-check", "--surface", "external", "--n-dirty", "4", "--n-clean", "2", "--out", str(out)]
        )
        == 0
    )
    res = json.loads(out.read_text())
    assert res["surface"] == "external" and res["seed"] == 11 and res["clean_n"] == 2
    assert [c["clutter_k"] for c in res["candidates"]] == list(CANDIDATES)
    # a larger factor can only keep fewer layered draws dirty (the rule only adds a condition)
    kept = [c["layered_kept"] for c in res["candidates"]]
    assert kept == sorted(kept, reverse=True)
