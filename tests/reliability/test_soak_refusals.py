"""The soak counts the viewpoints the arm refused (issue 19: 0 in the soak and the demo)."""

from __future__ import annotations

from cellctl.bench.reliability.soak import refused_viewpoints
from cellctl.messages import CycleResult, StationResult, ViewpointResult


def _result(views: list[ViewpointResult], stations: list[StationResult] | None) -> CycleResult:
    return CycleResult(cycle_id="c1", outcome="completed", viewpoints=views, stations=stations)


def test_refused_viewpoints_count_errors_but_not_relooks_and_say_why():
    views = [
        ViewpointResult(index=0, label="clean"),
        ViewpointResult(index=1, error="no collision-free path within 3 s", station=0, surface="external"),
        ViewpointResult(index=2, error="unreachable", relook_of=1),  # a re-look is not a planned viewpoint
    ]
    n, why = refused_viewpoints(_result(views, None))
    assert n == 1 and why == ["viewpoint 1 (station 0, external): no collision-free path within 3 s"]
    assert refused_viewpoints(_result([ViewpointResult(index=0, label="dirty")], None)) == (0, [])


def test_a_stations_refusals_count_when_its_views_are_not_listed():
    st = [StationResult(station=0, refused={"external": 2, "internal": 1}), StationResult(station=1)]
    assert refused_viewpoints(_result([ViewpointResult(index=0, label="clean")], st))[0] == 3


def test_the_demo_table_counts_refusals_as_the_soak_does():
    """A whole-bin result cut for the wire keeps its stations' refusal counts: the demo's ``ref`` column
    reports them, not only the refused views still listed."""
    from cellctl.bench.demo.runner import Row, fill

    st = [StationResult(station=0, refused={"external": 2}), StationResult(station=1)]
    row = Row(n=1, story="s")
    fill(row, _result([ViewpointResult(index=0, label="clean")], st))
    assert row.refused == 2
