"""Generated (reference, new view) pairs (cellctl.bench.classify.pairs)."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.bench.classify.pairs import BIN_POSE_ERROR, _cycle_poses, make_pair_source, perturb
from cellctl.classify.reference import pose_delta
from cellctl.geometry.transforms import look_at


def test_perturb_moves_the_camera_by_the_asked_delta() -> None:
    """Translation and rotation of the new pose against the reference are exactly the asked ones."""
    T = look_at([0.1, -0.5, 0.3], [0, 0, 0], (0, 0, 1))
    mm, deg = pose_delta(T, perturb(T, 10.0, 0.5, np.random.default_rng(3)))
    assert mm == pytest.approx(10.0, abs=1e-9) and deg == pytest.approx(0.5, abs=1e-9)


def test_a_cycle_pair_parks_the_bin_and_tells_only_the_measured_pose() -> None:
    """As a commissioned cycle: both views are told the plan (the cycle knows measured poses only); the
    cameras truly stand within the pose measurement's error of it; the bin is parked 10 mm / 0.5° off
    (horizontal, yaw) at each, independently — it moves under the cabin's lights between the two."""
    T = look_at([0.1, -0.5, 0.3], [0, 0, 0], (0, 0, 1))
    for seed in range(5):
        T_ref, T_new, park_r, park_n, T_rt, T_nt = _cycle_poses(T, (10.0, 0.5), np.random.default_rng(seed))
        assert np.array_equal(T_ref, T) and np.array_equal(T_new, T)
        for park in (park_r, park_n):
            assert np.linalg.norm(park[:3, 3]) * 1000 == pytest.approx(10.0) and park[2, 3] == 0.0
            assert np.degrees(np.arccos(park[0, 0])) == pytest.approx(0.5)
        for Tt in (T_rt, T_nt):
            mm, deg = pose_delta(np.eye(4), Tt @ np.linalg.inv(T))  # the error E of E @ T_plan, bin frame
            assert mm <= BIN_POSE_ERROR[0] + 1e-6 and deg <= BIN_POSE_ERROR[1] + 1e-6
        assert not np.allclose(park_r, park_n)


def test_a_clean_internal_pair_is_a_perturbed_view_of_the_same_steel() -> None:
    """One seeded internal pair (the camera-moves draw): clean label, empty mask, the demo's delta, and a
    reference plane in front of the camera; the mirrored camera and arm darken or brighten some polished pixels."""

    def first(mirror: bool):  # the same seeded draws with and without the mirror overlay
        draw = make_pair_source("internal", mirror=mirror, cycle=False)
        rng = np.random.default_rng(0)
        for _ in range(20):
            p = draw(rng, False)
            if p is not None:
                return p
        raise AssertionError("20 draws gave no internal pair")

    pair = first(True)
    assert pair.label == 0 and not pair.mask.any() and pair.info["family"] == "none"
    mm, deg = pose_delta(pair.T_ref, pair.T_new)
    assert mm == pytest.approx(10.0, abs=1e-6) and deg == pytest.approx(0.5, abs=1e-6)
    assert 0.05 < pair.plane.distance < 2.0
    assert pair.ref.shape == pair.new.shape == (144, 256, 3)
    bare = first(False)
    assert np.array_equal(bare.T_ref, pair.T_ref)
    assert (np.abs(bare.ref.astype(int) - pair.ref.astype(int)).max(axis=2) > 20).any()
