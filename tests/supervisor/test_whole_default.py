"""Whole bin by default, and `clean` only on a bin seen enough (issue 35, item 4), over real Zenoh.

The daemon runs the shipped configuration (only its port and output folders private: no
``planner.whole.enabled`` or coverage pin of the conftest), driven like a PLC; worker doubles answer
the three-station plan of ``test_station_loop`` with views that see every face of a surface between
them (or, ``internal_share``, part of the internal surface).
"""

from __future__ import annotations

import numpy as np
import pytest
from mcap.reader import make_reader

from cellctl.bus import keys
from cellctl.config import load_config
from cellctl.messages import PlanLookupReply, PlanLookupRequest
from tests.conftest import cfg_overrides
from tests.fakes.workers import FakeCell
from tests.supervisor.test_cycle_over_zenoh import cell, plc  # noqa: F401 - the daemon and PLC fixtures
from tests.supervisor.test_station_loop import SURFACES_AT, WholeFakeCell
from tests.supervisor.test_station_loop import faces as faces  # the case-study faces per surface

PINS = ("planner.whole.enabled=", "classifier.verdict.min_seen_fraction=")


@pytest.fixture
def cfg(tmp_path, port):  # the shipped config on a private port and folders
    return load_config(None, [o for o in cfg_overrides(tmp_path, port) if not o.startswith(PINS)])


class WideWholeFakeCell(WholeFakeCell):
    """The three-station plan, its views splitting each surface's faces between them (``internal_share``
    of the internal faces; the rest no view sees)."""

    internal_share = 1.0

    def _lookup(self, req: PlanLookupRequest, p: bytes | None) -> PlanLookupReply:
        r = super()._lookup(req, p)
        if not r.hit:
            return r
        f = self.faces[req.surface]
        if req.surface == "internal":
            f = f[: int(len(f) * self.internal_share)]
        k = self.at or 0
        views = [(st, i) for st, surfs in enumerate(SURFACES_AT) if req.surface in surfs for i in range(2)]
        chunks = np.array_split(f, len(views))
        vps = [vp.model_copy(update={"faces": chunks[views.index((k, vp.index))].tolist()}) for vp in r.viewpoints]
        return r.model_copy(update={"viewpoints": vps})


def _cycle(plc, timeout: float = 30):  # noqa: F811
    plc.cmd("reset")
    plc.wait_state("Idle")
    assert plc.cmd("start").accepted
    plc.wait_state("Complete", timeout)
    return plc.results.get(timeout=5)


def test_a_fresh_default_config_runs_a_whole_bin_cycle_and_calls_a_seen_bin_clean(cfg, cell, plc, faces) -> None:  # noqa: F811
    assert cfg.planner.whole.enabled and cfg.classifier.verdict.min_seen_fraction == {"external": 0.6, "internal": 0.6}
    with WideWholeFakeCell(cfg, faces) as fake:
        res = _cycle(plc)
    assert res.outcome == "completed", res.reason
    assert all(q.whole for q in fake.lookups) and res.whole_plan_id == "whole-1"
    assert [s.station for s in res.stations] == [0, 1, 2] and sum(a.park for a in fake.approaches) == 3
    assert res.coverage_by_surface == pytest.approx({"external": 1.0, "internal": 1.0})
    assert res.verdict == "clean" and res.reason is None
    assert res.min_seen_fraction == {"external": 0.6, "internal": 0.6}
    last = plc.wait_for(lambda s: s.admin.last_cycle is not None and s.admin.last_cycle.cycle_id == res.cycle_id, 5)
    assert last.admin.last_cycle.verdict == "clean"


def test_a_partly_seen_whole_bin_cycle_is_incomplete_on_status_log_replay(cfg, cell, plc, faces, tmp_path) -> None:  # noqa: F811
    class Partial(WideWholeFakeCell):
        internal_share = 0.3

    with Partial(cfg, faces):
        res = _cycle(plc)
    assert res.outcome == "completed", res.reason
    seen = res.coverage_by_surface
    assert seen["external"] == pytest.approx(1.0) and 0 < seen["internal"] < 0.6
    assert res.verdict == "incomplete"
    assert res.reason.startswith(f"incomplete: no dirt seen, but internal {seen['internal']:.0%} seen, needs 60%")
    st = plc.wait_for(lambda s: s.admin.last_cycle is not None and s.admin.last_cycle.cycle_id == res.cycle_id, 5)
    last = st.admin.last_cycle
    assert last.verdict == "incomplete" and last.coverage_by_surface == seen
    assert last.min_seen_fraction == {"external": 0.6, "internal": 0.6}
    assert st.admin.prod_processed_count == 1 and st.admin.prod_defective_count == 0  # inspected, not defective
    with open(cfg.path(res.log), "rb") as f:
        (logged,) = [m for _, ch, m in make_reader(f).iter_messages() if ch.topic == keys.result(cfg.cell_id)]
    assert b'"verdict":"incomplete"' in logged.data.replace(b" ", b"")
    assert cell.index.get(res.cycle_id).verdict == "incomplete"
    # replay --verify gates with the minimum the log recorded, whatever the replaying config says
    from cellctl.recording.replay import verify
    from tests.fakes.workers import fake_identify
    from tests.supervisor.test_cycle_over_zenoh import _verify_config

    vcfg = _verify_config(tmp_path / "v", settle_s=0)
    vcfg.classifier.verdict.min_seen_fraction = {}
    report = verify(cfg.path(res.log), vcfg, timeout_s=30, identification=(fake_identify, cell.supervisor.catalog))
    assert report.ok, report.differences


def test_one_station_one_surface_by_config_is_incomplete_and_dirt_seen_stays_dirty(tmp_path, port) -> None:
    from cellctl.app import build_cell
    from cellctl.geometry.catalog import load_catalog
    from tests.fakes.workers import fake_identify
    from tests.supervisor.test_cycle_over_zenoh import Plc

    overrides = [o for o in cfg_overrides(tmp_path, port) if not o.startswith(PINS[1])]  # single-station pinned
    cfg = load_config(None, overrides)
    assert not cfg.planner.whole.enabled
    c = build_cell(cfg, identification=(fake_identify, load_catalog(cfg.path(cfg.catalog))))
    p = Plc(cfg)
    try:
        with FakeCell(cfg, dirty_viewpoints={4}):  # the second cycle's second view
            first = _cycle(p)
            second = _cycle(p)
    finally:
        p.close()
        c.close()
    assert first.outcome == "completed" and first.verdict == "incomplete" and first.stations is None
    assert first.coverage_by_surface["internal"] == 0.0 and 0 < first.coverage_by_surface["external"] < 0.01
    assert "external" in first.reason and "internal 0% seen, needs 60%" in first.reason
    assert second.verdict == "dirty" and second.reason is None  # dirt seen is dirt, however little was seen
