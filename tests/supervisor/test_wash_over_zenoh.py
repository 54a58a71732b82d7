"""Start mode=wash_and_verify over real Zenoh with worker doubles: the cycle washes what the
scan found dirty, re-inspects it and ends clean; dirt no nozzle pose reaches ends dirty."""

from __future__ import annotations

import pytest
from mcap.reader import make_reader

from cellctl.bus import topics
from tests.fakes.workers import FakeCell, fake_identify
from tests.supervisor.test_cycle_over_zenoh import _verify_config, cell, plc  # noqa: F401 - fixtures

# FakeCell's viewpoint i sees faces 2i, 2i+1 of the case-study mesh, the bin 1 m in front of the
# base: viewpoint 16's faces face the base (washable), viewpoint 1's the far side (out of reach)
WASHABLE, FAR = 16, 1


@pytest.fixture
def cfg(cfg):
    """FakeCell's views see two faces each: the coverage bound of a clean verdict is tested on its own
    (test_wash_steps), not here."""
    return cfg.model_copy(update={"wash": cfg.wash.model_copy(update={"min_seen_fraction": 0.0})})


def _cycle(client, **params) -> object:
    assert client.cmd("reset").accepted
    client.wait_state("Idle")
    assert client.cmd("start", **params).accepted
    client.wait_state("Complete", timeout=120)
    return client.results.get(timeout=5)


def test_a_washable_dirty_view_is_washed_re_inspected_and_the_bin_ends_clean(cfg, cell, plc, tmp_path) -> None:  # noqa: F811
    with FakeCell(cfg, n_viewpoints=WASHABLE + 1, dirty_viewpoints={WASHABLE}) as fake:
        res = _cycle(plc, mode="wash_and_verify")
    assert res.outcome == "completed" and res.verdict == "clean"
    assert res.wash is not None and res.wash.verdict == "clean" and res.wash.reason is None
    (r1,) = res.wash.rounds
    assert r1.dirty_faces_before == 2 and r1.dirty_faces_after == 0 and r1.sweeps_run == r1.sweeps_planned > 0
    assert fake.calls.count("wash") == r1.sweeps_planned  # one request per sweep
    # the re-inspection views are in the MCAP and the round's count, not in res.viewpoints (size limit)
    assert not any(v.wash_round for v in res.viewpoints)
    assert 0 < r1.reinspected_views < WASHABLE + 1  # only near the wash
    folder = cfg.path(res.log).parent / f"{res.cycle_id}.wash"
    assert len(r1.pictures) == 3 and all((folder / p).is_file() for p in r1.pictures)
    with open(cfg.path(res.log), "rb") as f:
        names = [ch.topic for _, ch, _ in make_reader(f).iter_messages()]
    assert names.count(topics.WASH_PLAN) == 1 and names.count(topics.WASH_ROUND) == 1
    # the log replays: the same wash plan request, sweeps, re-inspection and result
    from cellctl.recording.replay import verify

    vcfg = _verify_config(tmp_path / "v", 0)
    vcfg = vcfg.model_copy(update={"wash": cfg.wash})  # the replaying supervisor decides with the same bound
    report = verify(cfg.path(res.log), vcfg, 60, (fake_identify, cell.supervisor.catalog))
    assert report.ok, report.differences
    assert "Execute.washing" in report.states_replayed and "Execute.verifying" in report.states_replayed


def test_dirt_out_of_reach_ends_dirty_unwashable_with_no_wash_motion(cfg, cell, plc) -> None:  # noqa: F811
    with FakeCell(cfg, n_viewpoints=3, dirty_viewpoints={FAR}) as fake:
        res = _cycle(plc, mode="wash_and_verify")
    assert res.outcome == "completed" and res.verdict == "dirty"
    assert res.wash.verdict == "dirty" and res.wash.reason.startswith("unwashable: no nozzle pose reaches")
    assert res.wash.rounds == [] and res.wash.remaining_faces == [2 * FAR, 2 * FAR + 1]
    assert "wash" not in fake.calls and fake.calls.count("move") == 3


def test_an_evaluate_cycle_does_not_wash(cfg, cell, plc) -> None:  # noqa: F811
    with FakeCell(cfg, n_viewpoints=WASHABLE + 1, dirty_viewpoints={WASHABLE}) as fake:
        res = _cycle(plc)
    assert res.outcome == "completed" and res.verdict == "dirty" and res.wash is None
    assert "wash" not in fake.calls
