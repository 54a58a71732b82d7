"""wash_and_verify in a whole-bin cycle over real Zenoh with worker doubles (the three-station plan of
``test_station_loop``; the real wash planner): the round plans over every station scanned, washes from
the station the base stands at, parks again at the station whose plan sees the washed faces to
re-inspect them, and ends clean; a Hold during a sweep resumes at that station and sweep."""

from __future__ import annotations

import time

import numpy as np
import pytest
from mcap.reader import make_reader

from cellctl.bus import topics
from tests.supervisor.test_cycle_over_zenoh import cell, plc  # noqa: F401 - the daemon and PLC fixtures
from tests.supervisor.test_station_loop import BASES, WholeFakeCell
from tests.supervisor.test_station_loop import cfg as _whole_cfg  # noqa: F401 - planner.whole.enabled
from tests.supervisor.test_station_loop import faces as _faces  # noqa: F401

# faces 32, 33 of the case-study mesh face a base 1 m in front of the bin (test_wash_over_zenoh):
# station 0's external views see them (the bin is measured there, and at station 2, 1 m in front)
WASHABLE = (32, 33)


@pytest.fixture
def faces(_faces):  # noqa: F811
    rest = [int(f) for f in _faces["external"] if int(f) not in WASHABLE]
    ext = [WASHABLE[0], rest[0], WASHABLE[1], *rest[1:]]  # station 0: view 0 sees face 32, view 1 face 33
    out = dict(_faces)
    out["external"] = np.array(ext)
    return out


@pytest.fixture
def cfg(_whole_cfg):  # noqa: F811
    # the doubles' views see a few faces: the coverage bound of a clean verdict is tested in test_wash_steps
    return _whole_cfg.model_copy(update={"wash": _whole_cfg.wash.model_copy(update={"min_seen_fraction": 0.0})})


def _start(p) -> None:
    p.cmd("reset")
    p.wait_state("Idle")
    assert p.cmd("start", mode="wash_and_verify").accepted


def test_a_whole_bin_cycle_washes_re_inspects_from_the_station_seeing_it_and_ends_clean(cfg, cell, plc, faces) -> None:  # noqa: F811
    # classification 0: station 0's external view 0 (face 32) dirty, and its confirming re-look (1)
    with WholeFakeCell(cfg, faces, dirty_viewpoints={0, 1}) as fake:
        _start(plc)
        plc.wait_state("Complete", 120)
        res = plc.results.get(timeout=5)
    assert res.outcome == "completed", res.reason
    assert res.verdict == "clean" and res.wash is not None and res.wash.verdict == "clean", res.wash
    (r1,) = res.wash.rounds
    assert r1.dirty_faces_before >= 1 and r1.dirty_faces_after == 0 and r1.sweeps_run > 0
    assert fake.calls.count("wash") == r1.sweeps_run + len(r1.sweeps_refused)
    # parks: the scan's three, then station 0 again for the re-inspection (the wash ran from station 2)
    parks = [a for a in fake.approaches if a.park]
    assert len(parks) == 4 and np.allclose(parks[3].base_pose.matrix(), BASES[0])
    # re-inspected from station 0's external plan only (its two views see the washed faces)
    assert r1.reinspected_views == 2 and not any(v.wash_round for v in res.viewpoints)
    assert len(r1.pictures) == 3
    with open(cfg.path(res.log), "rb") as f:
        names = [ch.topic for _, ch, _ in make_reader(f).iter_messages()]
    assert names.count(topics.WASH_ROUND) == 1 and names.count(topics.WASH_PLAN) >= 1


def test_a_hold_during_a_whole_bin_wash_resumes_at_the_station_and_sweep(cfg, cell, plc, faces) -> None:  # noqa: F811
    with WholeFakeCell(cfg, faces, dirty_viewpoints={0, 1}, delays={"wash": 0.4}) as fake:
        _start(plc)
        deadline = time.monotonic() + 90
        while "wash" not in fake.calls and time.monotonic() < deadline:
            time.sleep(0.02)
        assert "wash" in fake.calls, "no wash sweep started"
        assert plc.cmd("hold").accepted
        plc.wait_state("Held")
        parks_held = sum(a.park for a in fake.approaches)
        assert plc.cmd("unhold").accepted
        plc.wait_state("Complete", 120)
        res = plc.results.get(timeout=5)
    assert res.outcome == "completed", res.reason
    assert res.wash.verdict == "clean"
    (r1,) = res.wash.rounds
    # the interrupted sweep ran again (its reply came after the Hold), none was counted refused
    assert r1.sweeps_refused == [] and r1.sweeps_run == r1.sweeps_planned
    assert fake.calls.count("wash") == r1.sweeps_planned + 1
    assert parks_held == 3 and sum(a.park for a in fake.approaches) == 4  # the Hold parked nothing again
