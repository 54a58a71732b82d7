"""Reference sets on disk (no bus): staging, versions, lookups, and what a lookup never trusts."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cellctl.errors import RecordingError
from cellctl.recording.references import (
    MANIFEST,
    ReferenceSetWriter,
    check_set_files,
    latest_set,
    lookup_reference,
    read_manifest,
    set_versions,
)

T_CAM = np.array([[1, 0, 0, 0.5], [0, 1, 0, 0.1], [0, 0, 1, 1.2], [0, 0, 0, 1.0]])
T_BIN = np.array([[1, 0, 0, 1.0], [0, 1, 0, 0.0], [0, 0, 1, 0.0], [0, 0, 0, 1.0]])


def _commission(root: Path, cycle: str, plan_id: str = "plan-1", n: int = 2) -> ReferenceSetWriter:
    w = ReferenceSetWriter(root, "case_study", cycle)
    for k in range(n):
        w.add(plan_id, "external", None, k, b"png-%d" % k, "png", T_CAM, T_BIN, None)
    w.finish("hmi:alice", None, {}, {})
    return w


def test_versions_count_up_and_the_newest_set_holding_the_plan_wins(tmp_path: Path) -> None:
    _commission(tmp_path, "c1")
    _commission(tmp_path, "c2", "plan-2")
    _commission(tmp_path, "c3")
    assert [v for v, _ in set_versions(tmp_path, "case_study")] == [1, 2, 3]
    assert lookup_reference(tmp_path, "case_study", "plan-1", 1).version == 3
    assert lookup_reference(tmp_path, "case_study", "plan-2", 0).version == 2
    ref = lookup_reference(tmp_path, "case_study", "plan-1", 0)
    assert ref.image.read_bytes() == b"png-0" and ref.plan_id == "plan-1"
    np.testing.assert_allclose(ref.T_bin_cam, np.linalg.inv(T_BIN) @ T_CAM)
    assert lookup_reference(tmp_path, "case_study", "plan-1", 2) is None
    assert lookup_reference(tmp_path, "other_bin", "plan-1", 0) is None


def test_a_set_without_manifest_or_with_a_damaged_one_is_never_looked_up(tmp_path: Path) -> None:
    _commission(tmp_path, "c1")
    w = ReferenceSetWriter(tmp_path, "case_study", "c2")  # claimed (v0002) but never finished
    w.add("plan-1", "external", None, 0, b"unfinished", "png", T_CAM, T_BIN, None)
    assert w.claim().name == "v0002"
    assert lookup_reference(tmp_path, "case_study", "plan-1", 0).version == 1
    (tmp_path / "case_study" / "v0001" / MANIFEST).write_text("{not json")
    assert latest_set(tmp_path, "case_study", "plan-1") is None
    with pytest.raises(RecordingError, match="v0001.*manifest"):
        read_manifest(tmp_path / "case_study" / "v0001" / MANIFEST)


def test_a_taken_version_is_skipped_and_names_stay_inside_the_root(tmp_path: Path) -> None:
    (tmp_path / "case_study" / "v0001").mkdir(parents=True)  # another cell claimed it, not finished yet
    w = ReferenceSetWriter(tmp_path, "case_study", "../../c1")
    path = w.add("../../etc", "external", None, 0, b"x", "png", T_CAM, None, None)
    assert tmp_path.resolve() in path.resolve().parents
    w.finish("hmi:alice", None, {}, {})
    assert w.version == 2 and lookup_reference(tmp_path, "case_study", "../../etc", 0).T_base_bin is None
    assert not list((tmp_path / "case_study").glob(".staging-*"))


def test_a_closed_set_takes_no_more_views_and_poses_must_be_transforms(tmp_path: Path) -> None:
    w = _commission(tmp_path, "c1")
    with pytest.raises(RecordingError, match="closed"):
        w.add("plan-1", "external", None, 5, b"late", "png", T_CAM, T_BIN, None)
    w2 = ReferenceSetWriter(tmp_path, "case_study", "c2")
    with pytest.raises(RecordingError, match="4x4"):
        w2.add("plan-1", "external", None, 0, b"x", "png", np.eye(3), None, None)
    with pytest.raises(RecordingError, match="no reference view"):
        w2.claim()


def test_check_set_files_names_an_edited_and_a_missing_image(tmp_path: Path) -> None:
    _commission(tmp_path, "c1")
    folder = tmp_path / "case_study" / "v0001"
    man = read_manifest(folder / MANIFEST)
    assert check_set_files(folder, man) == []
    (folder / "external" / "plan-1" / "0000.png").write_bytes(b"edited")
    (folder / "external" / "plan-1" / "0001.png").unlink()
    bad = check_set_files(folder, man)
    assert len(bad) == 2 and "edited or replaced" in bad[0] and "missing" in bad[1]


def test_the_cli_lists_sets_and_shows_a_viewpoints_reference(tmp_path: Path, capsys) -> None:
    import json

    from cellctl.cli import main

    _commission(tmp_path / "references", "c1")
    at = ["--set", f"planner.plans_dir={tmp_path / 'plans'}"]
    assert main(["references", "list", *at]) == 0
    (line,) = capsys.readouterr().out.splitlines()
    s = json.loads(line)
    assert s["version"] == 1 and s["declared_by"] == "hmi:alice" and s["plans"] == {"plan-1": 2}
    assert main(["references", "show", "--bin", "case_study", "--plan", "plan-1", "--viewpoint", "1", *at]) == 0
    ref = json.loads(capsys.readouterr().out)
    assert Path(ref["image"]).read_bytes() == b"png-1" and ref["T_base_cam"] == T_CAM.tolist()
    assert main(["references", "show", "--bin", "case_study", "--plan", "plan-9", "--viewpoint", "0", *at]) == 1
