"""The planner's whole-bin lookup: the newest usable whole record's stations, the nearest station."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.geometry.catalog import load_catalog
from cellctl.geometry.transforms import invert, transform_from_xyz_rpy
from cellctl.messages import PlanLookupRequest, PoseMsg
from cellctl.planning.planfile import write_document
from cellctl.planning.whole import WHOLE_FORMAT
from cellctl.sim.scene import observation_T_bin_cam
from cellctl.supervisor.context.identity import Identity
from cellctl.workers.planner import PlannerService

BASES = [
    transform_from_xyz_rpy((0.0, -1.1, -0.3), (0.0, 0.0, np.pi / 2)),
    transform_from_xyz_rpy((1.1, 0.0, -0.3), (0.0, 0.0, np.pi)),
]


def _record(svc: PlannerService, plan_id: str, created: str, *, sha: str | None = None) -> dict:
    bt = load_catalog(svc.cfg.path(svc.cfg.catalog)).get("case_study")
    return {
        "format": WHOLE_FORMAT,
        "plan_id": plan_id,
        "created": created,
        "bin_type": "case_study",
        "mesh_sha256": sha or svc._mesh("case_study").sha256,
        "robot_model_id": svc.robot.model_id(),
        "cycle_time_s": 150.0,
        "stations": [
            {
                "rank": 0,
                "T_bin_base": BASES[0].tolist(),
                "identify": {"T_bin_cam": observation_T_bin_cam(bt, 2).tolist(), "q": [0.0] * 6},
                "identify_reason": None,
                "plans": {"external": f"{plan_id}-0e", "internal": f"{plan_id}-0i"},
                "viewpoints": {"external": 3, "internal": 0},
            },
            {
                "rank": 1,
                "T_bin_base": BASES[1].tolist(),
                "identify": None,
                "identify_reason": "the board is not visible from this station",
                "plans": {"external": f"{plan_id}-1e", "internal": f"{plan_id}-1i"},
                "viewpoints": {"external": 2, "internal": 4},
            },
        ],
    }


def _write(svc: PlannerService, rec: dict, with_plans: bool = True) -> None:
    root = svc.plans_dir / "case_study"
    write_document(rec, root / "whole" / f"{rec['plan_id']}.json")
    if with_plans:
        for st in rec["stations"]:
            for surf, pid in st["plans"].items():
                if st["viewpoints"][surf]:
                    (root / surf).mkdir(parents=True, exist_ok=True)
                    (root / surf / f"{pid}.json").write_text("{}")  # present; the ordinary lookup skips it


@pytest.fixture
def svc(cfg):
    s = PlannerService(cfg, "t1")
    yield s
    s.close()


def _lookup(svc: PlannerService, T_base_bin: np.ndarray):
    req = PlanLookupRequest(bin_type="case_study", bin_pose=PoseMsg.from_matrix(T_base_bin), whole=True)
    return svc.on_lookup(req, None)


def test_without_a_whole_record_the_lookup_misses_saying_so(svc) -> None:
    r = _lookup(svc, invert(BASES[0]))
    assert not r.hit and r.reason == "no whole-bin plan for bin type 'case_study'" and r.stations == []


def test_the_newest_usable_record_answers_its_stations_and_the_nearest_one(svc) -> None:
    _write(svc, _record(svc, "w-old", "2026-01-01T00:00:00"))
    _write(svc, _record(svc, "w-new", "2026-02-01T00:00:00"))
    _write(svc, _record(svc, "w-newer-no-plans", "2026-03-01T00:00:00"), with_plans=False)
    _write(svc, _record(svc, "w-other-mesh", "2026-04-01T00:00:00", sha="0" * 64))
    r = _lookup(svc, invert(BASES[1]) @ transform_from_xyz_rpy((0.02, 0.0, 0.0), (0, 0, 0.01)))
    assert r.whole_plan_id == "w-new" and r.cycle_time_s == 150.0
    assert [s.station for s in r.stations] == [0, 1] and r.station == 1
    s0, s1 = r.stations
    assert s0.observation_index == 2 and s1.observation_index is None
    assert s0.plans == {"external": "w-new-0e"} and s1.plans == {"external": "w-new-1e", "internal": "w-new-1i"}
    assert s0.base_pose.frame_id == "bin" and np.allclose(s0.base_pose.matrix(), BASES[0])
    assert not r.hit  # the station plans here are placeholders: the ordinary lookup finds none usable
    assert _lookup(svc, invert(BASES[0])).station == 0


def test_a_record_whose_station_plans_are_gone_is_not_used(svc) -> None:
    _write(svc, _record(svc, "w-gone", "2026-03-01T00:00:00"), with_plans=False)
    r = _lookup(svc, invert(BASES[0]))
    assert r.stations == [] and "misses station plan(s) ['w-gone-0e'" in r.reason


def test_a_whole_plan_without_stations_fails_the_cycle_with_its_reason(svc, cfg) -> None:
    from cellctl.errors import PlanningError
    from cellctl.supervisor.steps.checking_cache import CheckingCache
    from tests.supervisor._scripted import ScriptedRun, context

    rec = _record(svc, "w-empty", "2026-05-01T00:00:00")
    rec["stations"], rec["reason"] = [], "no candidate station sees the bin"
    _write(svc, rec)
    r = _lookup(svc, invert(BASES[0]))
    assert not r.hit and r.whole_plan_id == "w-empty" and r.stations == []
    assert r.reason == "whole-bin plan w-empty has no station: no candidate station sees the bin"
    cfg.planner.whole.enabled = True
    ctx = context(cfg, identity=Identity(bin_type="case_study", T_base_bin=invert(BASES[0])))
    run = ScriptedRun(ctx, {("planner", "lookup"): (r, None)})
    with pytest.raises(PlanningError, match="no candidate station sees the bin"):
        CheckingCache()(run)  # not a miss: replanning would find no station again


def test_replay_reads_a_request_recorded_before_the_station_fields_with_todays_defaults() -> None:
    from cellctl.recording.replay import _as_today

    old = {"type": "cellctl/ApproachRequest", "v": 1, "observation_index": 1, "park": True}
    assert _as_today(old) == {**old, "base_pose": None, "observe": True}
    assert _as_today({"type": "cellctl/Nope", "v": 1}) == {"type": "cellctl/Nope", "v": 1}
