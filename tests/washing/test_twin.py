"""The twin's powder under spray passes: what a pass removes, where, and what it leaves alone."""

from __future__ import annotations

import math

import numpy as np

from cellctl.sim.ground_truth import PowderField, SprayPass
from cellctl.surface import EXTERNAL


def _field() -> PowderField:
    return PowderField(
        np.array([[0.0, 0.0, 0.0]]), np.array([0.05]), np.array([EXTERNAL], np.uint8), np.array([[0, 0, 1.0]]), 3
    )


def test_a_pass_keeps_one_minus_removal_under_the_jet_and_nothing_else_changes() -> None:
    f = _field()
    pts = np.array([[0.0, 0.0, 0.0], [0.02, 0.0, 0.0], [0.0, 0.04, 0.0], [0.0, 0.0, 0.0]])
    nrm = np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0], [0, 0, -1.0]])  # the last: the wall's other side
    before = f.alpha(pts[:3], np.zeros(3, np.uint8), nrm[:3])
    # a sweep along x at y = 0, jet straight down onto the face
    f.wash(SprayPass(np.array([[-0.05, 0, 0], [0.05, 0, 0]]), np.array([[0, 0, -1.0]] * 2), 0.025, 0.5, 0.8))
    assert np.allclose(f.remaining(pts, nrm), [0.2, 0.2, 1.0, 1.0])
    f.wash(SprayPass(np.array([[0.05, 0, 0], [-0.05, 0, 0]]), np.array([[0, 0, -1.0]] * 2), 0.025, 0.5, 0.8))
    assert np.allclose(f.remaining(pts, nrm), [0.04, 0.04, 1.0, 1.0])
    after = f.alpha(pts[:3], np.zeros(3, np.uint8), nrm[:3])
    assert np.allclose(after, before * np.array([0.04, 0.04, 1.0]))


def test_an_oblique_jet_washes_its_stretched_footprint_within_the_incidence_limit() -> None:
    """A jet 50° off the normal: a point 1.3 radii from the spot along the tilt is still under the
    jet's cylinder (footprint stretched by 1/cos 50°); a jet beyond the incidence limit washes nothing."""
    f = _field()
    a = np.array([math.sin(math.radians(50)), 0.0, -math.cos(math.radians(50))])
    pts = np.array([[0.0, 0.0, 0.0], [1.3 * 0.025, 0.0, 0.0], [0.0, 0.03, 0.0]])
    nrm = np.tile([0, 0, 1.0], (3, 1))
    f.wash(SprayPass(np.array([[0.0, 0, 0]]), a[None], 0.025, math.cos(math.radians(60)), 0.8))
    assert np.allclose(f.remaining(pts, nrm), [0.2, 0.2, 1.0])
    g = _field()
    g.wash(SprayPass(np.array([[0.0, 0, 0]]), a[None], 0.025, math.cos(math.radians(40)), 0.8))
    assert np.allclose(g.remaining(pts, nrm), 1.0)


def test_the_bench_dirt_map_from_ground_truth_marks_the_twins_dirty_faces() -> None:
    """bench wash plans from face_p = largest opacity at centroid/corners: at the 0.5 threshold
    exactly the faces the twin calls dirty, before and after a wash."""
    from cellctl.bench.wash import gt_dirt_map
    from cellctl.classify.heatmap import face_probabilities
    from cellctl.config import load_config
    from cellctl.geometry.catalog import load_catalog, read_bin_mesh

    cfg = load_config()
    cat = load_catalog(cfg.path(cfg.catalog), cfg.root)
    mesh = read_bin_mesh(cat.mesh_path("tote"))
    f = PowderField.sample(mesh, 0.5, 11)
    p = face_probabilities(gt_dirt_map(f, mesh), mesh.n_faces)
    assert ((p > 0.5) == f.dirty_faces(mesh)).mean() > 0.995  # byte quantisation at the threshold
    c = f.centres[0]
    f.wash(SprayPass(c[None], -f.normals[:1], 0.1, 0.5, 1.0))
    p = face_probabilities(gt_dirt_map(f, mesh), mesh.n_faces)
    assert ((p > 0.5) == f.dirty_faces(mesh)).mean() > 0.995
