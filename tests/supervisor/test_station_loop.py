"""The whole-bin cycle's station loop over real Zenoh: worker doubles answer a three-station plan.

Station 0 and 2 see the board; station 1 does not (its bin pose is carried over). Each station has
both surfaces except station 2 (external only), so the loop runs next_surface and next_station.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from cellctl.geometry.catalog import load_catalog
from cellctl.geometry.transforms import invert, transform_from_xyz_rpy
from cellctl.messages import (
    ApproachReply,
    ApproachRequest,
    PlanLookupReply,
    PlanLookupRequest,
    PlannedViewpoint,
    PoseMsg,
    StationInfo,
)
from cellctl.surface import FACE_TAG
from tests.fakes.workers import CAM_POSE, FakeCell
from tests.supervisor.test_cycle_over_zenoh import cell, plc  # noqa: F401 - the daemon and PLC fixtures

# where fake_identify puts the bin (1 m in front of the base): station 0's planned pose, so it matches
T_BASE_BIN0 = transform_from_xyz_rpy((1.0, 0.0, 0.0), (0, 0, 0))
BASES = [
    invert(T_BASE_BIN0),
    transform_from_xyz_rpy((1.2, 0.0, 0.0), (0.0, 0.0, np.pi)),
    transform_from_xyz_rpy((0.0, 1.2, 0.0), (0.0, 0.0, -np.pi / 2)),
]
SURFACES_AT = [("external", "internal"), ("external", "internal"), ("external",)]


def _stations() -> list[StationInfo]:
    return [
        StationInfo(
            station=k,
            base_pose=PoseMsg.from_matrix(BASES[k], "bin"),
            observation_index=None if k == 1 else 0,
            identify_reason="board not visible" if k == 1 else None,
            plans={s: f"st{k}-{s}" for s in SURFACES_AT[k]},
            viewpoints={s: 2 for s in SURFACES_AT[k]},
        )
        for k in range(3)
    ]


class WholeFakeCell(FakeCell):
    """Doubles whose planner answers a whole-bin plan; the robot remembers the station it parked at."""

    def __init__(self, cfg, faces: dict[str, np.ndarray], **kw) -> None:
        super().__init__(cfg, **kw)
        self.faces = faces
        self.approaches: list[ApproachRequest] = []
        self.lookups: list[PlanLookupRequest] = []
        self.at: int | None = None
        self.miss_at: set[tuple[int, str]] = set()

    def _approach(self, req: ApproachRequest, _: bytes | None) -> ApproachReply:
        self.approaches.append(req)
        if req.park:
            self.at = (
                0
                if req.base_pose is None
                else next(k for k, T in enumerate(BASES) if np.allclose(T, req.base_pose.matrix(), atol=1e-6))
            )
        return super()._approach(req, _)

    def _lookup(self, req: PlanLookupRequest, _: bytes | None) -> PlanLookupReply:
        self._guard("lookup")
        self.lookups.append(req)
        assert req.whole
        k = self.at or 0
        whole = {"whole_plan_id": "whole-1", "stations": _stations(), "station": k, "cycle_time_s": 170.0}
        if (k, req.surface) in self.miss_at or req.surface not in SURFACES_AT[k]:
            return PlanLookupReply(hit=False, reason="beyond tolerance", **whole)
        f = self.faces[req.surface]
        base = 4 * k
        vps = [
            PlannedViewpoint(index=i, camera_pose=CAM_POSE, joints=[0.1 * i] * 6, faces=[int(f[base + 2 * i])])
            for i in range(2)
        ]
        return PlanLookupReply(
            hit=True, plan_id=f"st{k}-{req.surface}", viewpoints=vps, mesh_faces=int(self.faces["n"][0]), **whole
        )


@pytest.fixture
def faces(cfg) -> dict[str, np.ndarray]:
    mesh = load_catalog(cfg.path(cfg.catalog)).load_mesh("case_study")
    out = {s: np.flatnonzero(mesh.surface == FACE_TAG[s]) for s in ("external", "internal")}
    out["n"] = np.array([mesh.n_faces])
    return out


@pytest.fixture
def cfg(cfg):  # the conftest's cfg with the whole-bin cycle on
    cfg.planner.whole.enabled = True
    return cfg


def _run(p) -> object:
    p.cmd("reset")
    p.wait_state("Idle")
    assert p.cmd("start").accepted
    p.wait_state("Complete", 30)
    return p.results.get(timeout=5)


def test_the_cycle_visits_every_station_and_both_surfaces(cfg, cell, plc, faces) -> None:  # noqa: F811
    with WholeFakeCell(cfg, faces, dirty_viewpoints={5, 6}) as fake:  # the sixth view, and its confirming re-look
        res = _run(plc)
    assert res.outcome == "completed", res.reason
    # first park nominal (stations unknown), then stations 1 and 2 at their planned poses
    parks = [a for a in fake.approaches if a.park]
    assert [a.base_pose is None for a in parks] == [True, False, False]
    assert np.allclose(parks[1].base_pose.matrix(), BASES[1]) and parks[1].observe is False
    assert np.allclose(parks[2].base_pose.matrix(), BASES[2]) and parks[2].observe is True
    # lookups: station 0 ext, int; station 1 ext, int (carried-over pose = planned); station 2 ext
    assert [q.surface for q in fake.lookups] == ["external", "internal", "external", "internal", "external"]
    assert np.allclose(fake.lookups[2].bin_pose.matrix(), invert(BASES[1]), atol=1e-9)
    where = [(v.station, v.surface, v.index) for v in res.viewpoints if v.relook_of is None]
    assert where == [(k, s, i) for k in range(3) for s in SURFACES_AT[k] for i in range(2)]
    assert [(v.station, v.surface, v.index) for v in res.viewpoints if v.relook_of is not None] == [(1, "external", 1)]
    assert res.verdict == "dirty"  # the sixth view: station 1, external, index 1, confirmed
    assert res.plan_id == res.whole_plan_id == "whole-1" and res.modelled_cycle_s == 170.0
    assert [s.station for s in res.stations] == [0, 1, 2]
    assert [s.bin_pose_source for s in res.stations] == ["measured", "carried_over", "measured"]
    assert res.stations[2].plan_ids == {"external": "st2-external"} and res.stations[0].refused == {
        "external": 0,
        "internal": 0,
    }
    cov = res.coverage_by_surface
    assert cov["external"] > 0 and cov["internal"] > 0 and 0 < res.coverage < 1
    # the union of stations: each station's share is below the surface's whole-cycle coverage
    ext = [s.coverage["external"] for s in res.stations]
    assert all(0 < c < cov["external"] for c in ext)
    assert sum(ext) == pytest.approx(cov["external"], rel=1e-6)  # disjoint faces per station here
    assert set(res.dirt_map["seen_dirty"]) == {int(faces["external"][4 * 1 + 2 * 1])}
    assert res.dirt_map["coverage_by_surface"] == cov


def test_a_miss_at_a_later_station_ends_the_cycle_with_that_station_replanned(cfg, cell, plc, faces) -> None:  # noqa: F811
    with WholeFakeCell(cfg, faces) as fake:
        fake.miss_at = {(2, "external")}
        res = _run(plc)
    assert res.outcome == "replan_required"
    assert "at station 2 (external)" in res.reason and res.planner_job_id == "job-1"
    assert [s.station for s in res.stations] == [0, 1, 2]
    assert res.stations[2].reason.startswith("the cycle ended at this station")
    assert len([v for v in res.viewpoints if v.station == 0]) == 4  # what was scanned stays in the result


def test_hold_at_a_station_resumes_there(cfg, cell, plc, faces) -> None:  # noqa: F811
    with WholeFakeCell(cfg, faces, move_delay_s=0.15) as fake:
        plc.cmd("reset")
        plc.wait_state("Idle")
        plc.cmd("start")
        deadline = time.monotonic() + 20
        while fake.calls.count("move") < 5 and time.monotonic() < deadline:  # station 1, external
            time.sleep(0.02)
        assert plc.cmd("hold").accepted
        plc.wait_state("Held")
        held_parks = sum(a.park for a in fake.approaches)
        assert plc.cmd("unhold").accepted
        plc.wait_state("Complete", 30)
        res = plc.results.get(timeout=5)
    assert res.outcome == "completed", res.reason
    where = [(v.station, v.surface, v.index) for v in res.viewpoints]
    assert sorted(where) == sorted((k, s, i) for k in range(3) for s in SURFACES_AT[k] for i in range(2))
    assert held_parks == 2 and sum(a.park for a in fake.approaches) == 3  # no station parked twice


def test_a_first_park_at_no_station_drives_to_the_first_station(cfg, cell, plc, faces) -> None:  # noqa: F811
    class Elsewhere(WholeFakeCell):
        def _lookup(self, req, p):
            r = super()._lookup(req, p)
            if self.at is None or (self.at == 0 and sum(a.park for a in self.approaches) == 1):
                return r.model_copy(update={"hit": False, "viewpoints": [], "reason": "beyond tolerance"})
            return r

    with Elsewhere(cfg, faces) as fake:
        res = _run(plc)
    assert res.outcome == "completed", res.reason
    parks = [a for a in fake.approaches if a.park]
    assert parks[0].base_pose is None and np.allclose(parks[1].base_pose.matrix(), BASES[0])
    assert len(parks) == 4 and len(res.viewpoints) == 10


def test_replay_verify_passes_on_a_whole_bin_cycle(cfg, cell, plc, faces, tmp_path) -> None:  # noqa: F811
    from cellctl.recording.replay import verify
    from tests.fakes.workers import fake_identify
    from tests.supervisor.test_cycle_over_zenoh import _verify_config

    with WholeFakeCell(cfg, faces, dirty_viewpoints={2}):
        res = _run(plc)
    assert res.outcome == "completed", res.reason
    vcfg = _verify_config(tmp_path / "v", settle_s=0)  # single-station config: the log says whole-bin
    report = verify(cfg.path(res.log), vcfg, timeout_s=30, identification=(fake_identify, cell.supervisor.catalog))
    assert report.ok, report.differences
    assert "Execute.next_station" in report.states_replayed
