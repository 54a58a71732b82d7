"""A CycleResult too large for the wire is cut to fit, least telling views first; one that fits goes whole."""

from __future__ import annotations

from cellctl.bus.codec import decode_as, encode
from cellctl.messages import CycleResult, ViewpointResult
from cellctl.supervisor.publisher import fit_to_wire


def _result(n_clean: int, n_dirty: int, heat: str | None) -> CycleResult:
    views = [ViewpointResult(index=i, label="clean", p_dirty=0.01, heatmap=heat) for i in range(n_clean)]
    views += [ViewpointResult(index=n_clean + i, label="dirty", p_dirty=0.99, heatmap=heat) for i in range(n_dirty)]
    return CycleResult(cycle_id="c1", outcome="completed", verdict="dirty", viewpoints=views)


def test_a_result_that_fits_goes_whole() -> None:
    res = _result(10, 2, "ab" * 50)
    data = fit_to_wire(res)
    assert data == encode(res)
    assert decode_as(CycleResult, data).viewpoints_omitted is None


def test_heat_maps_go_first_then_clean_views_and_the_dirty_views_stay() -> None:
    heat = "x" * 600
    res = _result(150, 20, heat)
    assert len(encode(res)) > 64 * 1024
    # Without heat maps 170 views fit: only the maps go.
    got = decode_as(CycleResult, fit_to_wire(res))
    assert len(got.viewpoints) == 170 and all(v.heatmap is None for v in got.viewpoints)
    assert got.viewpoints_omitted == 170
    # A smaller limit leaves out the clean views, never a dirty one.
    limit = len(encode(_result(0, 20, None))) + 2000
    small = decode_as(CycleResult, fit_to_wire(res, limit), max_bytes=limit)
    assert [v.label for v in small.viewpoints] == ["dirty"] * 20
    assert small.viewpoints_omitted == 170
    assert small.verdict == "dirty" and small.cycle_id == "c1"


def test_views_without_heat_maps_are_counted_only_when_left_out() -> None:
    res = _result(2000, 5, None)
    got = decode_as(CycleResult, fit_to_wire(res))
    assert [v.index for v in got.viewpoints] == [2000, 2001, 2002, 2003, 2004]
    assert got.viewpoints_omitted == 2000
