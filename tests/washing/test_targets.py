"""Wash targets: the margin around dirty faces, across a sharp edge onto a face no view saw clean."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.config import load_config
from cellctl.geometry.catalog import load_catalog, read_bin_mesh
from cellctl.washing.targets import dilate, seen_clean_from_map


@pytest.fixture(scope="module")
def leg():
    """The case-study bin and two sides of one of its 5 cm square legs: the -y side (dirty in the
    dirt map) and the -x side next to it, 90° on, no view's (where the powder of demo story 3 lay)."""
    cfg = load_config()
    cat = load_catalog(cfg.path(cfg.catalog), cfg.root)
    mesh = read_bin_mesh(cat.mesh_path("case_study"))
    tri = mesh.vertices[mesh.faces]
    on_leg = (tri[:, :, 0].min(1) > -0.431) & (tri[:, :, 0].max(1) < -0.379)
    on_leg &= (tri[:, :, 1].min(1) > 0.309) & (tri[:, :, 1].max(1) < 0.361) & (tri[:, :, 2].max(1) < -0.44)
    minus_y = np.flatnonzero(on_leg & (mesh.normals[:, 1] < -0.99))
    minus_x = np.flatnonzero(on_leg & (mesh.normals[:, 0] < -0.99))
    assert len(minus_y) >= 2 and len(minus_x) >= 1
    return mesh, minus_y, minus_x


def _on_corner(mesh, minus_y) -> int:
    """The -y side's triangle with an edge on the leg's corner (x = -0.43): a long sliver."""
    on = (mesh.vertices[mesh.faces[minus_y]][:, :, 0] < -0.429).sum(axis=1) >= 2
    return int(minus_y[np.argmax(on)])


def _one(mesh, f) -> np.ndarray:
    out = np.zeros(mesh.n_faces, bool)
    out[f] = True
    return out


def test_margin_crosses_a_square_edge_onto_an_unseen_side(leg) -> None:
    mesh, minus_y, minus_x = leg
    # the -y side's long sliver whose edge the -x side shares; the -x side's centroids lie ~20 cm
    # from it, beyond any margin
    f = _on_corner(mesh, minus_y)
    t = dilate(mesh, _one(mesh, f), 0.02)
    assert t[minus_x].any(), "the side 90° on, touching the dirty face, is not washed"


def test_margin_does_not_cross_onto_a_side_seen_clean(leg) -> None:
    mesh, minus_y, minus_x = leg
    f = _on_corner(mesh, minus_y)
    clean = np.zeros(mesh.n_faces, bool)
    clean[minus_x] = True
    assert not dilate(mesh, _one(mesh, f), 0.02, clean)[minus_x].any()


def test_margin_on_a_flat_neighbour_still_stops_at_its_centroid(leg) -> None:
    mesh, minus_y, _ = leg
    # the two triangles of the -y side share a 58 cm edge; the other's centroid is ~20 cm away
    a, b = int(minus_y[0]), int(minus_y[1])
    assert not dilate(mesh, _one(mesh, a), 0.02)[b]
    assert dilate(mesh, _one(mesh, a), 0.25)[b]


def test_seen_clean_from_map() -> None:
    assert seen_clean_from_map({"seen_dirty": [3]}, 10, 0.5) is None
    got = seen_clean_from_map({"seen_dirty": [3], "seen_clean": [1, 2, 99]}, 10, 0.5)
    assert got is not None and np.flatnonzero(got).tolist() == [1, 2]
