"""Whole-bin plans within a cycle budget; joint windows, half turns and detours (issue 19, round 6)."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.planning.whole import WholeParams, plan_whole, wrap_window
from cellctl.planning.whole.timing import _detour
from tests.planning.test_whole import FAST, STATIONS, _every_viewpoint_connected

FLOORS = {"external": 75.0, "internal": 55.0}  # below what the box plan sees (84 / 63 % of the bounds)


def test_wrap_window_puts_a_stations_configurations_on_one_arc_within_the_limits(robot):
    rng = np.random.default_rng(4)
    Q = np.tile(robot.q_home, (40, 1)) + rng.normal(0.0, 0.05, (40, 6))
    # base joint around 0 (facing the bin), wrapped towards home at π: both sides of the cut at 0 / 2π
    Q[:, 0] = np.where(np.arange(40) % 2 == 0, rng.uniform(0.0, 0.5, 40), rng.uniform(-0.5, 0.0, 40) + 2 * np.pi)
    into = wrap_window(Q, robot, robot.q_home)
    W = into(Q)
    assert np.ptp(Q[:, 0]) > 5.0 and np.ptp(W[:, 0]) < 1.0  # one arc: no full turn between neighbours
    assert np.allclose(np.mod(W - Q + np.pi, 2 * np.pi) - np.pi, 0.0, atol=1e-9)  # the same arm (2π turns)
    assert np.array_equal(W[:, [1, 2]], Q[:, [1, 2]])  # ±π joints untouched
    assert ((W >= robot.q_min - 1e-9) & (W <= robot.q_max + 1e-9)).all()
    # a configuration of the same station added later (a replacement) lands in the same window
    late = Q[:1].copy()
    late[0, 0] = 0.25 + 2 * np.pi
    assert abs(into(late)[0, 0] - 0.25) < 1e-9 or abs(into(late)[0, 0] - 0.25 - 2 * np.pi) < 1e-9
    assert np.ptp(np.r_[W[:, 0], into(late)[:, 0]]) < 1.0


class _Ball:
    """A world whose only obstacle is a joint-space ball: a motion is free when it stays outside."""

    def __init__(self, centre, radius, blocked_all=False):
        self.c, self.r, self.blocked_all = np.asarray(centre, float), radius, blocked_all

    def motion_free(self, A, B, step):
        A, B = np.atleast_2d(A), np.atleast_2d(B)
        if self.blocked_all:
            return np.zeros(len(A), dtype=bool)
        t = np.linspace(0.0, 1.0, 200)
        P = A[:, None, :] + (B - A)[:, None, :] * t[None, :, None]
        return np.linalg.norm(P - self.c, axis=2).min(axis=1) > self.r


def test_a_detour_goes_round_what_the_straight_move_hits_and_stays_short_of_home(robot):
    home = robot.q_home
    a = home + np.array([-1.0, 1.5, 0.0, 0.0, 0.0, 0.0])
    b = home + np.array([1.0, 1.5, 0.0, 0.0, 0.0, 0.0])
    world = _Ball(0.5 * (a + b), 0.3)
    assert not world.motion_free(a, b, 0.004)[0]
    P = _detour(a, b, home, world, 0.004)
    assert P is not None and np.array_equal(P[0], a) and np.array_equal(P[-1], b) and 3 <= len(P) <= 4
    assert world.motion_free(P[:-1], P[1:], 0.004).all()
    via_home = float(np.abs(home - a).max() + np.abs(b - home).max())
    assert float(np.abs(np.diff(P, axis=0)).max(axis=1).sum()) < via_home  # shorter than via home
    assert _detour(a, b, home, _Ball(a, 0.1, blocked_all=True), 0.004) is None


@pytest.fixture(scope="module")
def unbudgeted(box, robot):
    params = WholeParams(plan=FAST, stations=STATIONS, chains="needed", min_bound_pct=FLOORS, workers=1)
    return plan_whole(box, params, robot)


def test_a_cycle_budget_trims_down_to_the_floors_and_keeps_every_viewpoint_connected(unbudgeted, box, robot):
    budget = unbudgeted.cycle_time_s - 8.0
    params = WholeParams(
        plan=FAST, stations=STATIONS, chains="needed", min_bound_pct=FLOORS, workers=1, cycle_budget_s=budget
    )
    plan = plan_whole(box, params, robot)
    _every_viewpoint_connected(plan, box, robot)
    assert plan.cycle_time_s < unbudgeted.cycle_time_s
    assert plan.counts.get("budget_trimmed", 0) > 0 or plan.counts.get("budget_fewer_stations", 0) == 1
    for surf, pct in FLOORS.items():  # the floors hold: the budget is paid by what lies above them
        s = plan.surfaces[surf]
        assert s.seen_m2 >= pct / 100.0 * s.bound_m2 - 1e-9
        assert s.seen_m2 <= unbudgeted.surfaces[surf].seen_m2 + 1e-9
    assert plan.counts["unverified_moves"] <= unbudgeted.counts["unverified_moves"]
    # a budget the plan is within changes nothing
    roomy = plan_whole(
        box,
        WholeParams(
            plan=FAST,
            stations=STATIONS,
            chains="needed",
            min_bound_pct=FLOORS,
            workers=1,
            cycle_budget_s=unbudgeted.cycle_time_s + 1.0,
        ),
        robot,
    )
    assert roomy.cycle_time_s == unbudgeted.cycle_time_s and "budget_trimmed" not in roomy.counts


def test_the_budget_comes_from_the_cell_config_and_refuses_a_negative_one():
    from cellctl.config import CellConfig
    from cellctl.errors import PlanningError
    from cellctl.planning.plan import PlanParams

    cfg = CellConfig()
    assert cfg.planner.whole.cycle_budget_s == 180.0
    assert WholeParams.for_cell(cfg, PlanParams()).cycle_budget_s == 180.0
    assert WholeParams().cycle_budget_s == 0.0  # a bare parameter set: no budget
    with pytest.raises(PlanningError, match=r"cycle_budget_s -1.0 must be ≥ 0"):
        WholeParams(cycle_budget_s=-1.0).check()


class _Free:
    """A world without obstacles."""

    def motion_free(self, A, B, step):
        return np.ones(len(np.atleast_2d(A)), dtype=bool)


def test_a_tour_on_the_wrong_2pi_turn_is_shifted_as_a_whole_the_same_arm_and_never_slower(robot):
    from cellctl.planning.whole import TimingModel
    from cellctl.planning.whole.timing import _shift_tour

    timing = TimingModel()
    rng = np.random.default_rng(5)
    # identification with the base joint at -2.5 rad, the next surface's tour at -2.8 rad: the tour
    # between them sits a turn away (3.2..3.6 rad), as case study seed 5's second station did
    q_prev = robot.q_home + np.r_[0.0, 0.3, 0.4, 0.0, 0.2, 0.0]
    q_prev[0] = -2.5
    tour = np.tile(q_prev, (5, 1)) + rng.normal(0.0, 0.1, (5, 6))
    tour[:, 0] = np.linspace(3.2, 3.6, 5)
    nodes = np.vstack([q_prev[None], tour])
    order = np.arange(6)
    paths = [np.array([nodes[a], nodes[b]]) for a, b in zip(order[:-1], order[1:], strict=True)]
    secs = [timing.motion_s(p) for p in paths]
    after = q_prev[None] + np.r_[-0.3, 0.1, 0.0, 0.0, 0.0, 0.0]
    end_s = timing.motion_s(np.array([nodes[-1], after[0]]))
    got = _shift_tour(q_prev, nodes, order, paths, secs, end_s, after, robot, _Free(), timing, robot.q_home, 0.004)
    assert got is not None
    new_nodes, new_order, new_paths, new_secs = got
    assert np.allclose(robot.fk_cam(new_nodes[1:]), robot.fk_cam(nodes[1:]), atol=1e-9)  # the same arm
    assert np.all(np.abs(new_nodes[1:, 0] - (-2.5)) < 1.5)  # on the identification's turn
    assert robot.within_limits(new_nodes).all()
    out_new = min(timing.motion_s(np.array([new_nodes[int(new_order[-1])], a])) for a in after)
    assert new_secs[0] + out_new < secs[0] + end_s - 3.0  # seconds saved at both ends
    assert sum(new_secs[1:]) == pytest.approx(sum(secs[1:]))  # its own moves take as long
    assert np.array_equal(new_paths[0][0], q_prev) and np.array_equal(new_paths[0][-1], new_nodes[int(new_order[1])])
    # a tour already on the right turn is left as it is
    same = _shift_tour(
        q_prev, new_nodes, new_order, new_paths, new_secs, out_new, after, robot, _Free(), timing, robot.q_home, 0.004
    )
    assert same is None
