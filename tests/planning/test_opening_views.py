"""Internal viewpoints through the top opening (issue 35: reach into cavities behind a narrow opening)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from cellctl.errors import PlanningError
from cellctl.planning.viewpoints import OPENING_ANCHORS_M, OPENING_FAR_MARGIN_M, concat, opening_viewpoints

DOV = (0.175, 0.6)


def test_an_opening_view_looks_from_the_anchor_or_as_far_back_as_the_depth_of_view_allows():
    near_seed, deep_seed = [0.2, 0.0, -0.3], [0.5, 0.3, -1.0]
    vp = opening_viewpoints(np.array([near_seed, deep_seed]), np.array([3, 4]), DOV, first_rank=2)
    D = len(OPENING_ANCHORS_M)
    assert len(vp) == 2 * D
    assert vp.rank.tolist() == [2 + j for j in range(D)] * 2 and vp.seed.tolist() == [0] * D + [1] * D
    o, k = vp.T[:, :3, 3], vp.T[:, :3, 2]
    anchors = np.c_[np.zeros((D, 2)), OPENING_ANCHORS_M]
    P = vp.seed_point
    # every view looks at its seed, along the line from its anchor
    to_seed = (P - o) / np.linalg.norm(P - o, axis=1, keepdims=True)
    assert np.allclose(to_seed, k)
    line = P - np.vstack([anchors, anchors])
    assert np.allclose(np.cross(line, k), 0.0, atol=1e-12)
    d = np.linalg.norm(P - o, axis=1)
    # the near seed is seen from the anchors themselves, the deep one from the depth of view's far end
    assert np.allclose(o[:D], anchors)
    assert np.allclose(d[D:], DOV[1] - OPENING_FAR_MARGIN_M)
    assert np.all(d >= DOV[0])


def test_a_depth_of_view_too_short_for_opening_views_is_refused():
    with pytest.raises(PlanningError, match=r"\[0.2, 0.24\]"):
        opening_viewpoints(np.zeros((1, 3)) - [0, 0, 0.5], np.zeros(1, int), (0.2, 0.24), first_rank=2)


def test_concat_keeps_both_batches_in_order():
    a = opening_viewpoints(np.array([[0.0, 0.0, -0.5]]), np.array([1]), DOV, first_rank=2)
    b = opening_viewpoints(np.array([[0.1, 0.0, -0.5]]), np.array([2]), DOV, first_rank=5)
    c = concat(a, b)
    assert len(c) == len(a) + len(b)
    assert c.rank.tolist() == a.rank.tolist() + b.rank.tolist()
    assert c.seed_face.tolist() == [1] * len(a) + [2] * len(b)


def test_a_narrow_opening_hopper_is_reached_into_only_with_opening_views():
    """Family mesh mixed_7 (narrow square opening over a deep hopper): from one inner station the fixed
    distances put nearly every internal camera inside the cavity; the opening views are reached."""
    from cellctl.geometry.family import family_mesh
    from cellctl.geometry.transforms import invert
    from cellctl.planning import pipeline as pl
    from cellctl.planning.collision import PlanningWorld
    from cellctl.planning.plan import PlanParams
    from cellctl.planning.raycast import RayCaster
    from cellctl.planning.robot import default_robot_model
    from cellctl.planning.stations import StationParams, candidate_stations

    mesh = family_mesh("mixed", 7)
    robot = default_robot_model()
    st = next(c for c in candidate_stations(mesh, None, StationParams(inner_candidates=4)) if c.ring == 1)
    sf = np.flatnonzero(mesh.surface_mask("internal"))
    reached = {}
    for on in (False, True):
        p = PlanParams(surface="internal", seed_pct=4.0, opening_views=on)
        s = pl.Setup(
            mesh=mesh,
            robot=robot,
            params=p,
            T_bin_base=st.T_bin_base,
            T_base_bin=invert(st.T_bin_base),
            q_start=robot.q_home,
            surf_faces=sf,
            world=PlanningWorld(mesh, robot, st.T_bin_base, margin=p.margin),
            rays=RayCaster(mesh.vertices, mesh.faces),
            rng=np.random.default_rng(0),
        )
        stages = pl._Stages(None, False)
        stages.start("generate_filter", "generate+filter")
        filt = pl.generate_and_filter(s, stages)
        stages.start("reachability", "reachability")
        reached[on] = len(pl.reach(replace(s), filt.vp, stages).reached.index)
    assert reached[False] <= 3
    assert reached[True] >= 3 * max(reached[False], 3)
