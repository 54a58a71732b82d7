"""Wash planning on the case-study bin: what is planned, what is refused, and that the twin ends clean."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.config import load_config
from cellctl.errors import PlanningError
from cellctl.geometry.catalog import load_catalog, read_bin_mesh
from cellctl.planning.robot import default_robot_model
from cellctl.sim.ground_truth import PowderField
from cellctl.sim.scene import nominal_T_bin_base
from cellctl.surface import EXTERNAL
from cellctl.washing.nozzle import NozzleModel
from cellctl.washing.plan import MAX_SWEEP_STEP_RAD, WashParams, plan_wash
from cellctl.washing.twin import wash_in_twin


@pytest.fixture(scope="module")
def bin_case():
    cfg = load_config()
    cat = load_catalog(cfg.path(cfg.catalog), cfg.root)
    bt = cat.get("case_study")
    mesh = read_bin_mesh(cat.mesh_path("case_study"))
    return mesh, nominal_T_bin_base(bt, mesh)


def _spot(mesh, centre, normal, radius=0.04) -> PowderField:
    return PowderField(
        np.array([centre], float), np.array([radius]), np.array([EXTERNAL], np.uint8), np.array([normal], float), 7
    )


def test_no_dirt_map_is_a_reason_and_no_motion(bin_case) -> None:
    mesh, T = bin_case
    plan = plan_wash(mesh, None, [T], NozzleModel(), default_robot_model())
    assert not plan.moves and "no dirt map" in plan.reason
    plan = plan_wash(mesh, {"seen_dirty": [], "seen_clean": [1, 2]}, [T], NozzleModel(), default_robot_model())
    assert not plan.moves and "nothing to wash" in plan.reason


def test_bad_dirt_map_and_no_station_are_errors(bin_case) -> None:
    mesh, T = bin_case
    with pytest.raises(PlanningError, match="seen_dirty id 99999"):
        plan_wash(mesh, {"seen_dirty": [3, 99999]}, [T], NozzleModel(), default_robot_model())
    with pytest.raises(PlanningError, match="at least one base pose"):
        plan_wash(mesh, {"seen_dirty": [3]}, [], NozzleModel(), default_robot_model())


def test_a_spot_on_the_board_side_is_swept_with_its_passes_and_the_twin_ends_clean(bin_case) -> None:
    """A powder clump on the wall facing the station: every dirty face gets the required passes
    by continuous sweeps, and running them in the twin leaves no dirty face."""
    mesh, T = bin_case
    nozzle = NozzleModel()
    field = _spot(mesh, (0.2, -0.37, -0.15), (0.0, -1.0, 0.0))
    dirty = field.dirty_faces(mesh)
    assert dirty.sum() >= 3
    plan = plan_wash(mesh, {"seen_dirty": np.flatnonzero(dirty).tolist()}, [T], nozzle, default_robot_model())
    assert plan.reason is None and plan.moves and not plan.unwashable
    assert np.all(plan.passes[dirty] >= nozzle.required_passes)
    assert plan.targets[dirty].all()
    for sw in plan.sweeps:
        assert np.abs(np.diff(sw.q, axis=0)).max(initial=0.0) <= MAX_SWEEP_STEP_RAD
        jets = sw.T_bin_noz[:, :3, 2]
        assert np.all(jets @ np.array([0.0, -1.0, 0.0]) < -0.5)  # spraying at the wall, not away from it
    washed_area = float(mesh.areas[plan.washed].sum())
    assert washed_area < 0.1 * float(mesh.areas.sum())  # a local wash, not the whole bin
    wash_in_twin(field, plan, mesh, nozzle)
    assert not field.dirty_faces(mesh).any()


def test_dirt_out_of_reach_is_unwashable_with_the_reason(bin_case) -> None:
    """Dirt on the far (+y) outside wall seen from the board-side station only: no motion, and
    the region is reported unwashable with why."""
    mesh, T = bin_case
    field = _spot(mesh, (0.0, 0.37, -0.5), (0.0, 1.0, 0.0))
    dirty = field.dirty_faces(mesh)
    assert dirty.any()
    plan = plan_wash(
        mesh, {"seen_dirty": np.flatnonzero(dirty).tolist()}, [T], NozzleModel(), default_robot_model(), WashParams()
    )
    assert not plan.moves
    assert plan.unwashable and "no nozzle pose reaches any dirty region" in plan.reason
    assert any("out of reach" in u.reason or "arm configuration" in u.reason for u in plan.unwashable)
    assert sum(u.area_m2 for u in plan.unwashable) == pytest.approx(float(mesh.areas[plan.targets].sum()))


def test_targets_come_from_face_p_above_the_threshold_or_from_seen_dirty() -> None:
    """A map with face_p: faces at or above the threshold (unseen ones never); without: seen_dirty."""
    from cellctl.classify.heatmap import FaceMap
    from cellctl.washing.targets import dirty_from_map

    p = np.array([0.1, 0.6, 0.5, 0.9, 0.0])
    seen = np.array([True, True, True, False, True])
    fm = FaceMap(p=p, seen=seen, dirty=seen & (p >= 0.5), dirty_area_m2=0.0).as_json()
    got, source = dirty_from_map(fm, 5, 0.55)
    assert source == "face_p" and got.tolist() == [False, True, False, False, False]
    got, source = dirty_from_map({"seen_dirty": [2, 4]}, 5, 0.55)
    assert source == "seen_dirty" and got.tolist() == [False, False, True, False, True]


def test_dilation_adds_nearby_faces_of_the_same_surface_only(bin_case) -> None:
    from cellctl.washing.targets import dilate

    mesh, _ = bin_case
    field = _spot(mesh, (0.2, -0.37, -0.15), (0.0, -1.0, 0.0))
    dirty = field.dirty_faces(mesh)
    assert (dilate(mesh, dirty, 0.0) == dirty).all()
    wide = dilate(mesh, dirty, 0.08)
    assert wide.sum() > dirty.sum() and wide[dirty].all()
    assert set(mesh.surface[wide].tolist()) == {EXTERNAL}
    d = np.linalg.norm(mesh.centroids[wide & ~dirty] - np.array([0.2, -0.37, -0.15]), axis=1)
    assert d.max() < 0.04 * 1.8 + 0.08 + 0.08  # clump reach + margin + a triangle


def test_the_residue_pass_covers_faces_the_first_pass_left_short(bin_case) -> None:
    """Seeded powder all over the bin, one station: the second cover pass (the residue's own jet
    directions, arm shape and rolls) sprays target faces the first pass left short, and only adds
    sweeps; without it those faces stay uncovered."""
    mesh, T = bin_case
    field = PowderField.sample(mesh, 0.3, 860361905)
    dm = {"seen_dirty": np.flatnonzero(field.dirty_faces(mesh)).tolist()}
    robot = default_robot_model()
    first = plan_wash(mesh, dm, [T], NozzleModel(), robot, WashParams(residue_rolls=0))
    both = plan_wash(mesh, dm, [T], NozzleModel(), robot, WashParams(cpu_budget_s=float("inf")))
    a = mesh.areas
    assert a[both.covered].sum() > 1.2 * a[first.covered].sum()
    assert not (first.covered & ~both.covered).any() and len(both.sweeps) > len(first.sweeps)
    assert both.counts["residue_points_left"] < both.counts["residue_points"]
    assert "residue_points" not in first.counts


def test_the_cpu_rate_predicts_a_station_from_the_measured_ones() -> None:
    """The plan's CPU ceiling: the first station always runs, a next one only when the CPU spent
    plus its waypoints at the rate measured on the stations so far fits."""
    from cellctl.washing.plan.budget import _CpuRate

    r = _CpuRate(8.5)
    assert r.fits(10_000, 0.0)  # nothing measured: the plan's first station always runs
    r.add(100, 2.0)  # 0.02 s per waypoint
    assert r.fits(100, 6.0) and not r.fits(200, 6.0)
    # a small station after a large one is priced by its waypoints, not by the large one's cost
    assert r.predict(10) == pytest.approx(0.2) and r.fits(10, 8.0)
    r.add(300, 2.0)  # the rate is over every station measured: 4 s / 400 waypoints
    assert r.predict(100) == pytest.approx(1.0)
    residue = _CpuRate(8.5, prior=0.06, first_free=False)
    assert not residue.fits(100, 3.0) and residue.fits(50, 3.0)
    assert _CpuRate(float("inf")).fits(10**9, 1e9)


def test_a_cpu_budget_leaves_stations_unplanned_and_counts_them(bin_case) -> None:
    """A budget below one station's cost: the first station is planned, every other one is
    counted over budget (its dirt left for the next round), and the residue pass tries none."""
    mesh, T = bin_case
    field = PowderField.sample(mesh, 0.3, 860361905)
    dm = {"seen_dirty": np.flatnonzero(field.dirty_faces(mesh)).tolist()}
    T2 = T.copy()
    T2[:3, 3] += np.array([0.0, 0.3, 0.0])
    plan = plan_wash(mesh, dm, [T, T2], NozzleModel(), default_robot_model(), WashParams(cpu_budget_s=1e-3))
    assert plan.counts["stations_over_budget"] == 1 and plan.counts["stations_used"] == 1
    assert plan.counts.get("residue_stations", 0) == 0 and plan.counts.get("residue_stations_over_budget", 0) >= 1
