"""Corrupt, truncated, foreign and hostile plan and model files: clean errors and cache misses, never a crash.

Plan files: whatever sits in ``plans_dir``, a lookup is a cache miss naming the bad file (or a
hit on the good plan beside it). Model files: :class:`ClassifierError` naming the path and what
was expected; the classifier worker still starts and answers that surface's requests with it.
Seeded.
"""

from __future__ import annotations

import json
import os
import pickle
import random
import shutil
from pathlib import Path

import numpy as np
import pytest

from cellctl.errors import ClassifierError
from cellctl.messages import PlanLookupRequest, PoseMsg
from cellctl.planning.planfile import (
    MAX_PLAN_BYTES,
    list_plans,
    plan_path,
    read_document,
    read_plan,
    write_document,
    write_plan,
)

ROOT = Path(__file__).resolve().parents[2]
MODELS = ROOT / "models" / "classifier"
SEED = 11
GOOD_PLAN = Path()
"""A real plan file, made once per session by :func:`good_plan_file` (the plan cache is not in git)."""


@pytest.fixture(scope="session", autouse=True)
def good_plan_file(tmp_path_factory) -> Path:
    """Plan the case-study bin (fast mode, seeded) like ``cellctl plan`` does, once."""
    global GOOD_PLAN
    from cellctl.config import load_config
    from cellctl.planning.mesh import load_catalog_mesh
    from cellctl.planning.pipeline import PlanParams, base_pose_from_xyz_yaw, make_plan
    from cellctl.planning.robot import default_robot_model

    cfg = load_config(None, [])
    mesh = load_catalog_mesh(cfg.path(cfg.catalog), "case_study")
    params = PlanParams(surface="external", seed_pct=10.0, mode="fast", seed=0)
    plan = make_plan(
        mesh, base_pose_from_xyz_yaw(0, -1.13, -0.33, 90), params, default_robot_model(), bin_type="case_study"
    )
    assert plan.viewpoints, plan.reason
    GOOD_PLAN = write_plan(plan, tmp_path_factory.mktemp("good-plan") / "good.json")
    return GOOD_PLAN


def _good_plan() -> dict:
    return read_document(GOOD_PLAN)


def _variant(**changes) -> dict:
    plan = json.loads(json.dumps(_good_plan()))
    plan.update(changes)
    return plan


def _not_plain_files(folder: Path, prefix: str, suffix: str, huge: int) -> dict[str, Path]:
    """A directory, a FIFO, a symlink loop, a dangling symlink and a sparse ``huge``-byte file."""
    out = {k: folder / f"{prefix}{k}{suffix}" for k in ("directory", "fifo", "symlink_loop", "dangling", "huge")}
    out["directory"].mkdir()
    os.mkfifo(out["fifo"])
    other = folder / f"{prefix}loop-b{suffix}"
    os.symlink(other, out["symlink_loop"])
    os.symlink(out["symlink_loop"], other)
    os.symlink(folder / "nowhere", out["dangling"])
    with open(out["huge"], "wb") as f:
        f.truncate(huge)  # sparse: no disk used
    return out


def _bad_plan_files(folder: Path, rng: random.Random) -> dict[str, Path]:
    """Write one bad file per kind into ``folder``; return kind -> path."""
    good = GOOD_PLAN.read_bytes()
    out: dict[str, Path] = {}

    def put(kind: str, data: bytes) -> None:
        out[kind] = folder / f"bad-{kind}.json"
        out[kind].write_bytes(data)

    put("empty", b"")
    put("random_bytes", rng.randbytes(4096))
    put("invalid_utf8", good[:100] + b"\xff\xfe" + good[100:])
    put("json_array", b"[1, 2, 3]")
    put("json_string", b'"cellctl-plan/1"')
    put("other_format", json.dumps({"format": "cellctl-plan/2", "sha256": "", "plan": {}}).encode())
    put("no_hash", json.dumps({"format": "cellctl-plan/1", "plan": _good_plan()}).encode())
    put("nesting_bomb", b"[" * 200_000)
    put("closed_bomb", b'{"format":"cellctl-plan/1","plan":' + b"[" * 5000 + b"]" * 5000 + b"}")
    put("huge_number", b'{"format":"cellctl-plan/1","sha256":' + b"9" * 5000 + b"}")
    put("model_file", (MODELS / "external.pt").read_bytes()[:200_000])
    for i in range(12):
        put(f"truncated_{i}", good[: rng.randrange(1, len(good))])
    for i in range(12):
        # a flip outside what the hash covers (JSON whitespace) leaves the plan intact: flip again
        for _ in range(100):
            flipped = bytearray(good)
            flipped[rng.randrange(len(flipped))] ^= 1 << rng.randrange(8)
            put(f"bitflip_{i}", bytes(flipped))
            try:
                read_plan(out[f"bitflip_{i}"])
            except Exception:
                break
    # intact (hash matches) but foreign: another bin type, surface, version of the contents
    foreign = {
        "other_bin_type": _variant(bin_type="other_bin"),
        "other_surface": _variant(surface="internal"),
        "no_plan_id": {k: v for k, v in _good_plan().items() if k != "plan_id"},
        "matrix_3x3": _variant(T_base_bin=[[1, 0, 0], [0, 1, 0], [0, 0, 1]]),
        "nan_matrix": _variant(T_base_bin=[[float("nan")] * 4] * 4),
        "viewpoints_string": _variant(viewpoints="many"),
        "joints_5": _variant(viewpoints=[{**_good_plan()["viewpoints"][0], "q": [0.0] * 5}]),
        "faces_floats": _variant(viewpoints=[{**_good_plan()["viewpoints"][0], "faces": [1.5]}]),
        "reachable_null": _variant(reachable=[None]),
        "params_list": _variant(params=[1]),
        "coverage_string": _variant(coverage="most"),
    }
    for kind, plan in foreign.items():
        out[kind] = write_document(plan, folder / f"bad-{kind}.json")
    out.update(_not_plain_files(folder, "bad-", ".json", MAX_PLAN_BYTES + 1))
    return out


def test_every_bad_plan_file_is_skipped_with_its_path_and_the_good_plan_still_found(tmp_path: Path) -> None:
    good = _good_plan()
    folder = plan_path(tmp_path, read_plan(GOOD_PLAN)).parent
    folder.mkdir(parents=True)
    bad = _bad_plan_files(folder, random.Random(SEED))
    plans, skipped = list_plans(tmp_path, "case_study", "external")
    assert plans == []  # only bad files so far
    text = "\n".join(skipped)
    for kind, path in bad.items():
        if kind.startswith("bitflip") and not any(str(path) in s for s in skipped):
            continue  # a flip that changed nothing the hash covers (e.g. a float's last digit) is fine
        assert str(path) in text, f"{kind}: {path.name} not reported"
    assert len(skipped) >= len(bad) - 13  # the loop's second link and flips that changed nothing
    shutil.copy(GOOD_PLAN, folder / GOOD_PLAN.name)
    plans, skipped_again = list_plans(tmp_path, "case_study", "external")
    assert [p.plan_id for p in plans] == [good["plan_id"]] or all(p.to_json() == good for p in plans)
    assert len(skipped_again) == len(skipped)


@pytest.fixture(scope="module")
def planner(tmp_path_factory):
    from cellctl.config import load_config
    from cellctl.workers.planner import PlannerService

    plans = tmp_path_factory.mktemp("plans")
    cfg = load_config(None, [f"planner.plans_dir={plans}"])
    service = PlannerService(cfg, "fuzz")
    yield service, plans
    service.close()


def test_the_planner_lookup_is_a_clean_miss_naming_the_bad_file(planner) -> None:
    service, plans = planner
    good = _good_plan()
    folder = plan_path(plans, read_plan(GOOD_PLAN)).parent
    folder.mkdir(parents=True, exist_ok=True)
    bad = _bad_plan_files(folder, random.Random(SEED + 1))
    req = PlanLookupRequest(bin_type="case_study", bin_pose=PoseMsg.from_matrix(np.asarray(good["T_base_bin"])))
    reply = service.on_lookup(req, None)
    assert not reply.hit
    assert "damaged plan file(s) skipped" in reply.reason and str(folder) in reply.reason
    shutil.copy(GOOD_PLAN, folder / GOOD_PLAN.name)
    reply = service.on_lookup(req, None)
    assert reply.hit and reply.plan_id == good["plan_id"] and reply.viewpoints, reply.reason
    assert "skipped" in reply.reason
    # a foreign plan that passes every file check but cannot be adjusted is still a miss, not a crash
    for p in folder.glob("*"):
        if p.is_file() or p.is_symlink():
            p.unlink()
    vps = [{**v, "T_bin_cam": [[0.0] * 4] * 4} for v in good["viewpoints"]]
    write_document({**json.loads(json.dumps(good)), "viewpoints": vps}, folder / "degenerate.json")
    reply = service.on_lookup(req, None)
    assert not reply.hit and reply.reason
    assert len(bad) > 40


# --- classifier model files -------------------------------------------------------------------


def _torch_save(obj, path: Path) -> Path:
    import torch

    torch.save(obj, path)
    return path


class _Evil:
    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def _bad_model_files(folder: Path, rng: random.Random) -> dict[str, Path]:
    import torch

    good_raw = (MODELS / "external.pt").read_bytes()
    good = torch.load(MODELS / "external.pt", map_location="cpu", weights_only=True)
    out: dict[str, Path] = {}

    def put(kind: str, data: bytes) -> None:
        out[kind] = folder / f"{kind}.pt"
        out[kind].write_bytes(data)

    def blob(kind: str, **changes) -> None:
        out[kind] = _torch_save({**good, **changes}, folder / f"{kind}.pt")

    put("empty", b"")
    put("random_bytes", rng.randbytes(10_000))
    put("plan_file", GOOD_PLAN.read_bytes())
    put("json", b'{"format": "cellctl-classifier/1"}')
    for i in range(6):
        put(f"truncated_{i}", good_raw[: rng.randrange(1, len(good_raw))])
    _Evil.marker = str(folder / "pwned")
    put("pickle_payload", pickle.dumps({"format": "cellctl-classifier/1", "x": _Evil()}))
    out["torch_pickle_payload"] = _torch_save({"format": "cellctl-classifier/1", "x": _Evil()}, folder / "tp.pt")
    out["a_list"] = _torch_save([1, 2, 3], folder / "a_list.pt")
    blob("other_format", format="cellctl-classifier/2")
    blob("other_surface", surface="internal")
    blob("other_arch_name", arch="vgg16")
    blob("resnet_label_lite0_weights", arch="resnet18")
    blob("other_architecture_weights", state_dict={"fc.weight": torch.zeros(2, 512), "fc.bias": torch.zeros(2)})
    blob("state_dict_not_tensors", state_dict={"a": 1})
    blob("state_dict_list", state_dict=[1])
    blob("no_input_size", input_size=None)
    blob("huge_input_size", input_size=10**6)
    blob("nan_mean", mean=[float("nan"), 0.0, 0.0])
    blob("zero_std", std=[0.0, 1.0, 1.0])
    blob("threshold_2", threshold=2.0)
    blob("band_string", uncertain_logit_band="wide")
    blob("negative_temperature", temperature=-1.0)
    out.update(_not_plain_files(folder, "", ".pt", 600 * 1024 * 1024))
    return out


def test_every_bad_model_file_is_a_classifier_error_naming_the_path(tmp_path: Path) -> None:
    from cellctl.classify.infer import SurfaceModel

    bad = _bad_model_files(tmp_path, random.Random(SEED))
    for kind, path in bad.items():
        with pytest.raises(ClassifierError) as err:
            SurfaceModel.load(path, surface="external")
        assert str(path) in str(err.value), (kind, str(err.value))
    assert not (tmp_path / "pwned").exists()  # the pickle payload never ran


@pytest.mark.parametrize(
    "card, match",
    [
        (b"\xff\xfe not json", "not valid JSON"),
        (b"[" * 100_000, "not valid JSON"),
        (b"[1, 2]", "expected an object"),
        (b'{"sha256": 12345}', "do not belong together"),
        (b'{"sha256": "0000"}', "do not belong together"),
    ],
)
def test_a_bad_model_card_names_the_card(tmp_path: Path, card: bytes, match: str) -> None:
    from cellctl.classify.infer import SurfaceModel

    shutil.copy(MODELS / "external.pt", tmp_path / "external.pt")
    (tmp_path / "external.json").write_bytes(card)
    with pytest.raises(ClassifierError, match=match) as err:
        SurfaceModel.load(tmp_path / "external.pt", surface="external")
    assert str(tmp_path / "external.json") in str(err.value)


def test_the_classifier_worker_starts_and_answers_a_bad_surface_with_the_reason(tmp_path: Path) -> None:
    import cv2

    from cellctl.messages import ClassifyRequest
    from cellctl.workers.classifier import ClassifierService

    (tmp_path / "external.pt").write_bytes((MODELS / "external.pt").read_bytes()[:5000])  # truncated
    shutil.copy(MODELS / "internal.pt", tmp_path / "internal.pt")
    shutil.copy(MODELS / "internal.json", tmp_path / "internal.json")
    service = ClassifierService(tmp_path, "fp32", threads=1)
    assert set(service.models) == {"internal"}
    assert str(tmp_path / "external.pt") in service.problems["external"]
    png = cv2.imencode(".png", np.full((64, 64, 3), 128, np.uint8))[1].tobytes()
    ext, internal = service.classify(
        [(ClassifyRequest(surface="external"), png), (ClassifyRequest(surface="internal"), png)]
    )
    assert isinstance(ext, ClassifierError) and str(tmp_path / "external.pt") in str(ext)
    assert internal.label in ("clean", "dirty")
