"""The typed plan: file round trip, plans written before the typed model, malformed plans refused."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from cellctl.errors import PlanCacheError
from cellctl.planning.adjust import lookup_plan
from cellctl.planning.pipeline import PlanParams, make_plan
from cellctl.planning.plan import Plan
from cellctl.planning.planfile import list_plans, plan_path, read_document, read_plan, write_document, write_plan

DATA = Path(__file__).parent / "data"
OLD_PLAN = DATA / "plan_v1_box_small.json"
"""``cellctl-plan/1`` files written by the untyped pipeline (commit a96af3b), all on the conftest box
with the base at BOX_BASE: fast mode, external surface, seed_pct 2, sa_iterations 300 (this one);
``plan_v1_box_paper.json`` the same in paper mode (paper_budget_s 0.05); and
``plan_v1_box_far_empty.json`` an empty plan (base at (4, 0, -0.1), seed_pct 5)."""
OLD_FILES = sorted(DATA.glob("plan_v1_*.json"))


def _keys(x: object) -> object:
    """The key structure of a JSON value (key order included), without the values."""
    if isinstance(x, dict):
        return [(k, _keys(v)) for k, v in x.items() if k != "camera"]
    if isinstance(x, list):
        return [_keys(x[0])] if x and isinstance(x[0], dict) else "list"
    return type(x).__name__


@pytest.fixture(scope="module")
def small_plan(box, robot, T_bin_base) -> Plan:
    return make_plan(box, T_bin_base, PlanParams(seed_pct=2, sa_iterations=300), robot, bin_type="box")


def test_a_plan_survives_the_plan_file_unchanged(small_plan, tmp_path):
    p = write_plan(small_plan, tmp_path / "a.json")
    back = read_plan(p)
    assert back.to_json() == json.loads(json.dumps(small_plan.to_json()))
    assert write_plan(back, tmp_path / "b.json").read_bytes() == p.read_bytes()  # same bytes again
    assert isinstance(back.viewpoints[0].T_bin_cam, np.ndarray) and back.viewpoints[0].T_bin_cam.shape == (4, 4)
    assert back.viewpoints[0].approach.shape[1] == 6 and back.viewpoints[0].faces.dtype == np.int64
    with pytest.raises(ValueError):
        back.viewpoints[0].q[0] = 1.0  # a plan is a record: its arrays are read-only


def test_the_plan_file_keeps_its_layout_and_optional_keys(small_plan):
    body = small_plan.to_json()
    assert list(body)[:3] == ["plan_id", "created", "bin_type"] and list(body)[-3:] == [
        "mesh_faces",
        "surface_faces",
        "sa",
    ]
    # fast mode: no paper-mode counter in the file; a finished plan has the exact-cover time
    assert "matrix_straight" in body["stage_counts"] and "matrix_rrtconnect_fallbacks" not in body["stage_counts"]
    assert list(body["times_s"])[-2:] == ["exact_cover_s", "total"]
    assert "job_id" not in body


@pytest.mark.parametrize("path", OLD_FILES, ids=lambda p: p.stem)
def test_every_old_plan_file_reads_and_writes_back_the_same_json(path):
    old = json.loads(path.read_text())["plan"]
    new = read_plan(path).to_json()
    cam_old, cam_new = old["params"].pop("camera"), new["params"].pop("camera")
    assert json.dumps(new) == json.dumps(old)  # same keys, same order, same values
    assert cam_new == {**cam_new, **cam_old}  # camera fields added since take their defaults


def test_new_plans_have_the_layout_of_old_ones(small_plan, box, robot):
    from cellctl.planning.pipeline import base_pose_from_xyz_yaw

    old = json.loads(OLD_PLAN.read_text())["plan"]
    body = small_plan.to_json()
    # the one key added since: on in new plans, absent (= off) in old files
    assert body["params"].pop("opening_views") is True
    assert _keys(body) == _keys(old)
    empty = make_plan(box, base_pose_from_xyz_yaw(4.0, 0.0, -0.1, 0.0), PlanParams(seed_pct=5), robot)
    old_empty = json.loads((DATA / "plan_v1_box_far_empty.json").read_text())["plan"]
    body = empty.to_json()
    body["params"].pop("opening_views")
    assert _keys(body) == _keys(old_empty)
    assert empty.to_json()["stage_counts"] == old_empty["stage_counts"]


def test_a_plan_file_written_before_the_typed_model_reads_and_still_hits(box, robot, tmp_path):
    old = json.loads(OLD_PLAN.read_text())["plan"]
    plan = read_plan(OLD_PLAN)  # the envelope's sha256 is checked, so the file is as the old code wrote it
    assert plan.plan_id == old["plan_id"] and len(plan.viewpoints) == len(old["viewpoints"]) == 8
    assert plan.counts.reachable == old["counts"]["reachable"] and plan.stage_counts.seeds == 34
    assert np.array_equal(plan.viewpoints[3].T_base_cam, np.array(old["viewpoints"][3]["T_base_cam"]))
    new = plan.to_json()
    # written again it is the same JSON, but for camera fields added since (their defaults)
    cam_old, cam_new = old["params"].pop("camera"), new["params"].pop("camera")
    assert new == old and list(new) == list(old)
    assert cam_new == {**cam_new, **cam_old}
    # and the lookup still uses it (same mesh hash, same robot model)
    assert plan.mesh_sha256 == box.sha256 and plan.robot_model_id == robot.model_id()
    dest = plan_path(tmp_path, plan)
    dest.parent.mkdir(parents=True)
    shutil.copy(OLD_PLAN, dest)
    hit = lookup_plan(tmp_path, "box", "external", plan.base.T_base_bin, box, robot, 20.0, 2.0)
    assert hit.hit and hit.plan_id == plan.plan_id and len(hit.viewpoints) == 8, hit.reason


def _bad(body: dict, **changes) -> dict:
    out = json.loads(json.dumps(body))
    for path, value in changes.items():
        *head, last = path.split("__")
        d = out
        for k in head:
            d = d[int(k)] if isinstance(d, list) else d[k]
        if value is _DROP:
            del d[last]
        else:
            d[last] = value
    return out


_DROP = object()


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"q_start": _DROP}, "q_start is not 6 finite joint angles"),
        ({"viewpoints__0__q": [0.0] * 5}, r"viewpoints\[0\]\.q is not 6 finite joint angles"),
        ({"reachable__2__faces": [1.5]}, r"reachable\[2\]\.faces is not a list of face ids"),
        ({"viewpoints__1__approach": [[0.0] * 5]}, r"viewpoints\[1\]\.approach is not a list of 6-joint waypoints"),
        ({"viewpoints__0__roll": _DROP}, r"viewpoints\[0\] lacks \['roll'\]"),
        ({"extra": 1}, r"unknown keys \['extra'\]"),
        ({"coverage": "most"}, "coverage is 'most', expected a finite number"),
        ({"counts__generated": _DROP}, "counts.generated is missing"),
        ({"stage_counts__seeds": 1.5}, "stage_counts.seeds is 1.5, expected an integer"),
        ({"params__speed": 3}, r"params has unknown keys \['speed'\]"),
        ({"params__margin": "thin"}, "params.margin is 'thin'"),
        ({"T_bin_base": np.eye(4).tolist()}, "T_bin_base and T_base_bin are not each other's inverse"),
        ({"T_base_bin": [[1.0, 0.0, 0.0]] * 3}, "T_base_bin is not a 4x4 matrix"),
        ({"plan_id": ""}, "plan_id is '', expected a non-empty string"),
        ({"sa__accepted": True}, "sa.accepted is True, expected an integer"),
    ],
)
def test_a_malformed_plan_is_refused_naming_the_file_and_the_field(small_plan, tmp_path, changes, message):
    p = write_document(_bad(small_plan.to_json(), **changes), tmp_path / "bad.json")
    read_document(p)  # intact envelope: the body is what is wrong
    with pytest.raises(PlanCacheError, match=message) as err:
        read_plan(p)
    assert str(p) in str(err.value) and "is malformed" in str(err.value)


def test_the_cache_skips_a_malformed_plan_beside_a_good_one(small_plan, tmp_path):
    good = write_plan(small_plan, plan_path(tmp_path, small_plan))
    bad = write_document(_bad(small_plan.to_json(), viewpoints__0__q=[0.0] * 5), good.parent / "bad.json")
    plans, skipped = list_plans(tmp_path, "box", "external")
    assert [p.plan_id for p in plans] == [small_plan.plan_id]
    assert len(skipped) == 1 and str(bad) in skipped[0] and "viewpoints[0].q" in skipped[0]
