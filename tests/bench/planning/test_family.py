"""``bench whole-bin --family`` (issue 35): the mesh range, the arm-aware summary, worst mesh first."""

from __future__ import annotations

import pytest

from cellctl.bench.planning.family import FAMILY_MESHES, _summary, parse_family, table
from cellctl.errors import ConfigError


def test_the_family_spec_names_a_family_and_its_mesh_range():
    assert parse_family("mixed") == ("mixed", list(range(FAMILY_MESHES)))
    assert parse_family("hopper:3-5") == ("hopper", [3, 4, 5])
    assert parse_family("open:7") == ("open", [7])
    with pytest.raises(ConfigError, match="'blob'"):
        parse_family("blob:0-3")
    with pytest.raises(ConfigError, match="'5-2'"):
        parse_family("mixed:5-2")
    with pytest.raises(ConfigError, match="'a-b'"):
        parse_family("mixed:a-b")


def _row(seed: int, internal: float, arm: float, cycle: float) -> dict:
    surf = {"area_fraction": 0.5, "viewpoints": 10, "reason": None, "area_m2": 2.0}
    return {
        "seed": seed,
        "stations": 2,
        "viewpoints": 40,
        "planning_s": 20.0,
        "planning_cpu_s": 15.0,
        "cycle_time_s": cycle,
        "cycle_s_per_m2": cycle / 3.0,
        "dropped_unconnected": 0,
        "unverified_moves": 0,
        "exact_cover": None,
        "surfaces": {
            "external": {**surf, "bound_fraction": 0.95, "arm_bound_fraction": 0.97, "arm_bound_of_bound": 0.98},
            "internal": {
                **surf,
                "bound_fraction": internal,
                "arm_bound_fraction": arm,
                "arm_bound_of_bound": internal / arm,
            },
        },
    }


def test_meshes_are_listed_worst_first_with_both_bounds():
    good = [_row(0, 0.98, 0.99, 150.0), _row(1, 0.96, 0.99, 160.0)]
    bad = [_row(0, 0.40, 0.95, 200.0), _row(1, 0.35, 0.96, 210.0)]
    s = _summary(bad)
    assert s["internal"]["arm_bound_fraction"] == {"median": pytest.approx(0.955), "worst": 0.95}
    assert s["cycle_s_per_m2"]["worst"] == pytest.approx(70.0)
    meshes = {name: {"shape": name, "summary": _summary(rows)} for name, rows in (("good", good), ("bad", bad))}
    t = table(meshes)
    assert [r["mesh"] for r in t] == ["bad", "good"]
    assert t[0]["internal"] == {
        "pct_bound": "37.5/35.0",
        "pct_arm_bound": "95.5/95.0",
        "arm_bound_pct_of_bound": "39.3/36.5",
    }
