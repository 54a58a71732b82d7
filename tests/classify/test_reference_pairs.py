"""Generated (reference, new view) pairs (cellctl.classify.reference_pairs)."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.classify.reference import pose_delta
from cellctl.classify.reference_pairs import make_pair_source, perturb
from cellctl.geometry.transforms import look_at


def test_perturb_moves_the_camera_by_the_asked_delta() -> None:
    """Translation and rotation of the new pose against the reference are exactly the asked ones."""
    T = look_at([0.1, -0.5, 0.3], [0, 0, 0], (0, 0, 1))
    mm, deg = pose_delta(T, perturb(T, 10.0, 0.5, np.random.default_rng(3)))
    assert mm == pytest.approx(10.0, abs=1e-9) and deg == pytest.approx(0.5, abs=1e-9)


def test_a_clean_internal_pair_is_a_perturbed_view_of_the_same_steel() -> None:
    """One seeded internal pair: clean label, empty mask, the demo's delta, and a reference plane in
    front of the camera; the mirrored camera and arm darken or brighten some polished pixels."""

    def first(mirror: bool):  # the same seeded draws with and without the mirror overlay
        draw = make_pair_source("internal", mirror=mirror)
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
