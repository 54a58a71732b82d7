"""``cellctl bench whole-bin``'s parts: the foreign mesh and the median/worst summary."""

from __future__ import annotations

import numpy as np

from cellctl.bench.planning.plans import foreign_mesh
from cellctl.bench.planning.rows import median_worst
from cellctl.cli.bench import BENCHES


def test_the_foreign_mesh_is_not_shaped_like_the_catalog_bins():
    m = foreign_mesh()
    lo, hi = m.vertices.min(axis=0), m.vertices.max(axis=0)
    size = hi - lo
    assert size[1] > 2 * size[0]  # long and narrow: the catalog bins are at most 1.5 : 1
    assert m.internal.any() and (~m.internal).any()
    assert abs(hi[2]) < 1e-9 and lo[2] < -0.8  # bin frame: origin at the top opening, +Z up
    assert np.isclose(m.areas.sum(), m.areas[m.internal].sum() + m.areas[~m.internal].sum())


def test_the_second_foreign_mesh_is_wide_low_and_narrow_necked():
    import pytest

    from cellctl.errors import PlanningError

    m = foreign_mesh("foreign_basin")
    lo, hi = m.vertices.min(axis=0), m.vertices.max(axis=0)
    size = hi - lo
    assert size[0] > size[2] and size[1] > size[2]  # wider than high: the catalog bins are higher than wide
    top = m.vertices[np.abs(m.vertices[:, 2]) < 1e-9]
    widest = float(np.linalg.norm(m.vertices[:, :2], axis=1).max())
    assert float(np.linalg.norm(top[:, :2], axis=1).min()) < 0.6 * widest  # an opening narrower than the body
    assert m.internal.any() and (~m.internal).any()
    with pytest.raises(PlanningError, match="unknown generated mesh 'cube'"):
        foreign_mesh("cube")


def _row(seed, ext, cycle, planning):
    return {
        "seed": seed,
        "stations": 3,
        "viewpoints": 50 + seed,
        "planning_s": planning,
        "planning_cpu_s": planning / 2,
        "cycle_time_s": cycle,
        "dropped_unconnected": 0,
        "unverified_moves": seed % 2,
        "exact_cover": {"stations": 3, "viewpoints": 40, "proven": seed != 1},
        "surfaces": {
            "external": {"area_fraction": ext * 0.9, "bound_fraction": ext, "viewpoints": 30, "reason": None},
            "internal": {"area_fraction": 0.0, "bound_fraction": 0.0, "viewpoints": 0, "reason": "no internal faces"},
        },
    }


def test_summary_reports_the_median_and_the_worst_direction_of_each_figure():
    rows = [_row(0, 0.95, 200.0, 20.0), _row(1, 0.90, 260.0, 35.0), _row(2, 0.93, 210.0, 25.0)]
    s = median_worst(rows)
    assert s["external"]["bound_fraction"] == {"median": 0.93, "worst": 0.90}  # worst coverage = lowest
    assert s["cycle_time_s"] == {"median": 210.0, "worst": 260.0}  # worst time = highest
    assert s["planning_s"]["worst"] == 35.0 and s["unverified_moves"]["worst"] == 1
    assert s["exact_cover_proven"] == 2
    assert s["exact_cover_stations"] == {"median": 3.0, "worst": 3.0}  # of the proven covers only
    rows[0]["exact_cover"] = rows[2]["exact_cover"] = {"stations": 7, "viewpoints": 90, "proven": False}
    assert median_worst(rows)["exact_cover_stations"] is None  # no proven cover: no bound
    assert s["internal"] == {"reason": "no internal faces"}


def test_bench_whole_bin_is_registered():
    assert BENCHES["whole-bin"][0] == "cellctl.bench.planning.plans:bench_whole_bin"


def test_a_bench_of_some_bins_refuses_an_unknown_bin_by_name():
    import pytest

    from cellctl.bench.options import BenchOptions
    from cellctl.bench.planning.plans import bench_bins
    from cellctl.errors import ConfigError

    with pytest.raises(ConfigError, match="case_stduy"):
        bench_bins(BenchOptions(n=1), only=["case_stduy"])
