"""The review item names the reference its view was compared with (a commissioned set), or none."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cellctl.config import load_config
from cellctl.hmi.records import CycleRecords
from cellctl.hmi.review import Review
from cellctl.recording.references import ReferenceSetWriter, reference_root


def test_a_view_judged_against_references_names_its_set_and_viewpoint(tmp_path: Path) -> None:
    cfg = load_config(None, [f"recording.dir={tmp_path / 'logs'}", f"planner.plans_dir={tmp_path / 'plans'}"])
    w = ReferenceSetWriter(reference_root(cfg), "case_study", "20261204T120000-000-1")
    w.add("plan-int-3", "internal", 3, 7, b"\x89PNG-ref", "png", np.eye(4), np.eye(4), None)
    w.finish("max", "whole-1", {}, {})
    review = Review(cfg, CycleRecords(cfg))
    res = {"bin": {"type": "case_study"}, "reference_version": 1, "decision_path": {"internal": "references"},
           "stations": [{"station": 3, "plan_ids": {"internal": "plan-int-3"}}]}  # fmt: skip
    ref = review._reference(res, {"index": 7, "station": 3}, "internal")
    assert ref is not None and (ref["version"], ref["plan_id"], ref["viewpoint"], ref["declared_by"]) == (
        1, "plan-int-3", 7, "max")  # fmt: skip
    assert Path(ref["_file"]).read_bytes() == b"\x89PNG-ref"
    # another viewpoint, another plan, or a surface judged by the detector alone: no reference
    assert review._reference(res, {"index": 8, "station": 3}, "internal") is None
    assert review._reference({**res, "stations": [{"station": 3, "plan_ids": {"internal": "replan"}}]},
                             {"index": 7, "station": 3}, "internal") is None  # fmt: skip
    assert review._reference({**res, "decision_path": {"internal": "enrolled"}}, {"index": 7, "station": 3},
                             "internal") is None  # fmt: skip
