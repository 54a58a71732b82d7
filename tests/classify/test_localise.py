"""Patch → face projection of heat maps (a face-index render per view), the board as an occluder,
the per-face-cell fusion and the bench's ground truth (docs/classifier/inspect.md, round 6)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from cellctl.classify.heatmap import (
    OFF_BIN,
    ON_BOARD,
    MeshCaster,
    ViewEvidence,
    footprint,
    fuse_config,
    fuse_views,
    patch_evidence,
)
from cellctl.config import VerdictConfig
from cellctl.errors import ClassifierError
from cellctl.geometry.catalog import BinMesh

G = 16


def _plate() -> BinMesh:
    """A 2 m square at z = 0 as two triangles: 0 = below the diagonal y = x, 1 = above it."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    return BinMesh(v, np.array([[0, 1, 2], [0, 2, 3]]), np.zeros(2, np.uint8), name="plate")


def _looking_down(x: float = 0.0) -> tuple[np.ndarray, SimpleNamespace]:
    """A camera 1 m above (x, 0), optical +Z down, image x = plate x, image y = −plate y; its
    160² image spans exactly ±1 m, so patch (i, j) of a 16² map is 0.125 m of plate a side."""
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [x, 0.0, 1.0]
    return T, SimpleNamespace(fx=80.0, fy=80.0, cx=79.5, cy=79.5, width=160, height=160)


def _one_hot(i: int, j: int, p: float = 0.99, rest: float = 0.01) -> np.ndarray:
    heat = np.full((G, G), rest)
    heat[i, j] = p
    return heat


def test_the_footprint_is_a_face_index_render_of_the_patches() -> None:
    mesh = _plate()
    T, intr = _looking_down(x=1.0)  # the image spans x 0..2: its right half is past the plate
    fp = footprint(MeshCaster(mesh), T, intr, G, sub=4)
    assert len(fp.cell) == (G * 4) ** 2
    col = fp.cell % G
    assert (fp.face[col < 7] >= 0).all()
    assert (fp.face[col >= 8] == OFF_BIN).all()
    # rows of the image run down the plate's −y: the first row is above the diagonal at x < y
    row = fp.cell // G
    assert set(fp.face[(row == 0) & (col == 0)].tolist()) == {1}
    assert set(fp.face[(row == G - 1) & (col == 6)].tolist()) == {0}


def test_a_spot_between_a_large_faces_sample_points_reaches_it_through_its_patch() -> None:
    mesh = _plate()
    T, intr = _looking_down()
    # patch (14, 14) is plate (0.8125, -0.8125): inside face 0 by its right-angle corner, 1.6 patches
    # from its nearest inner sample point (2/3, -2/3), so the four samples see no heat
    views = [ViewEvidence(np.array([0, 1]), T, _one_hot(14, 14), 0.99)]
    samples = fuse_views(views, mesh, intr, prior=0.2, face_threshold=0.7)
    assert not samples.dirty[0]
    patches = fuse_views(views, mesh, intr, prior=0.2, face_threshold=0.7, projection="patches")
    assert patches.dirty.tolist() == [True, False]
    assert patches.seen.tolist() == [True, True]
    # a second view's clean patch over the same spot takes it back (the views add per face cell)
    two = views + [ViewEvidence(np.array([0, 1]), T, np.full((G, G), 0.01), 0.01)]
    assert not fuse_views(two, mesh, intr, prior=0.2, face_threshold=0.7, projection="patches").dirty[0]


def test_patches_on_the_id_board_give_no_evidence() -> None:
    mesh = _plate()
    T, intr = _looking_down()
    board = np.array([[0.7, -0.9, 0.01], [0.9, -0.9, 0.01], [0.9, -0.7, 0.01], [0.7, -0.7, 0.01]])
    caster = MeshCaster(mesh, board)
    fp = footprint(caster, T, intr, G)
    assert (fp.face[fp.cell == 14 * G + 14] == ON_BOARD).all()
    views = [ViewEvidence(np.array([0, 1]), T, _one_hot(14, 14), 0.99)]
    fm = fuse_views(views, mesh, intr, prior=0.2, face_threshold=0.7, projection="patches", caster=caster)
    assert not fm.dirty.any()
    # a patch next to the board (its rays all on steel) still counts
    views = [ViewEvidence(np.array([0, 1]), T, _one_hot(14, 11), 0.99)]
    fm = fuse_views(views, mesh, intr, prior=0.2, face_threshold=0.7, projection="patches", caster=caster)
    assert fm.dirty.tolist() == [True, False]


def test_a_face_that_fills_little_of_a_hot_patch_gets_less_dirty_evidence() -> None:
    mesh = _plate()
    T, intr = _looking_down()
    fp = footprint(MeshCaster(mesh), T, intr, G)
    heat = _one_hot(7, 8)  # plate (0.0625, 0.0625): the diagonal runs through the patch's corner
    full_k, full_z = patch_evidence(heat, fp, [0, 1], 2, cells=1, share_full=0.0)
    part_k, part_z = patch_evidence(heat, fp, [0, 1], 2, cells=1, share_full=1.0)
    assert full_k.tolist() == part_k.tolist() == [0, 1]
    assert (full_z > 1.0).all()  # both faces lie under the hot patch's centre region
    assert (part_z < full_z).all() and (part_z > 0).all()
    # faces the plan does not list for the view get nothing from it
    keys, _ = patch_evidence(heat, fp, [1], 2, cells=1)
    assert keys.tolist() == [1]


def test_fuse_config_follows_the_verdict_config_and_refuses_an_unknown_projection() -> None:
    mesh = _plate()
    T, intr = _looking_down()
    views = [ViewEvidence(np.array([0, 1]), T, _one_hot(14, 14), 0.99)]
    assert fuse_config(views, mesh, intr, VerdictConfig()).dirty.tolist() == [True, False]
    assert not fuse_config(views, mesh, intr, VerdictConfig(projection="samples")).dirty.any()
    with pytest.raises(ClassifierError, match="projection"):
        fuse_views(views, mesh, intr, projection="rays")
    with pytest.raises(ValueError, match="projection"):
        VerdictConfig(projection="rays")
    # a whole-image model's view (no heat map) paints every cell of its faces with its p_dirty
    coarse = fuse_views([ViewEvidence(np.array([1]), T, None, 0.99)], mesh, intr, projection="patches")
    assert coarse.dirty.tolist() == [False, True] and coarse.seen.tolist() == [False, True]


def test_the_bench_truth_finds_a_small_clump_between_the_ten_old_sample_points() -> None:
    from cellctl.bench.classify.inspect import TRUTH_GRID, _dirty_faces, _dirty_faces_10pt
    from cellctl.sim.ground_truth import PowderField

    # one 20 cm triangle; the clump (8 mm) sits on the dense grid point farthest from the old ten
    v = np.array([[0, 0, 0], [0.2, 0, 0], [0, 0.2, 0]], float)
    mesh = BinMesh(v, np.array([[0, 1, 2]]), np.zeros(1, np.uint8), name="tri")
    tri = v
    c = tri.mean(axis=0)
    old = np.array([*tri, (tri[0] + tri[1]) / 2, (tri[1] + tri[2]) / 2, (tri[2] + tri[0]) / 2, c, *((c + tri) / 2)])
    k = TRUTH_GRID
    grid = np.array(
        [(a * tri[0] + b * tri[1] + (k - a - b) * tri[2]) / k for a in range(k + 1) for b in range(k + 1 - a)]
    )
    far = grid[np.argmax(np.min(np.linalg.norm(grid[:, None] - old[None], axis=2), axis=1))]
    r = 0.008
    assert np.min(np.linalg.norm(old - far, axis=1)) > 1.6 * r  # past the clump's halo too
    field = PowderField(far[None], np.array([r]), np.zeros(1, np.uint8), np.array([[0.0, 0.0, 1.0]]), 3)
    assert not _dirty_faces_10pt(field, mesh)[0]
    assert _dirty_faces(field, mesh)[0]


def test_the_case_study_board_occludes_the_patches_in_front_of_it() -> None:
    from cellctl.classify.heatmap import board_quad
    from cellctl.config import load_config
    from cellctl.geometry.catalog import load_catalog

    cfg = load_config()
    catalog = load_catalog(cfg.path(cfg.catalog), cfg.root)
    bt, mesh = catalog.get("case_study"), catalog.load_mesh("case_study")
    Tb = np.asarray(bt.T_bin_board(), float)
    w, h = bt.board.size_m
    centre = (Tb @ np.array([w / 2, h / 2, 0.0, 1.0]))[:3]
    T = np.eye(4)  # 0.4 m in front of the board, looking at it (the board's +z points into the wall)
    T[:3, 0], T[:3, 2] = Tb[:3, 0], Tb[:3, 2]
    T[:3, 1] = np.cross(T[:3, 2], T[:3, 0])
    T[:3, 3] = centre - 0.4 * Tb[:3, 2]
    intr = SimpleNamespace(fx=160.0, fy=160.0, cx=79.5, cy=79.5, width=160, height=160)
    fp = footprint(MeshCaster(mesh, board_quad(bt)), T, intr, G)
    assert (fp.face[fp.cell == 8 * G + 8] == ON_BOARD).all()
    assert (fp.face >= 0).mean() > 0.1  # the wall around the board (the rim above it is past the bin)
    views = [ViewEvidence(np.arange(mesh.n_faces), T, np.full((G, G), 0.99), 0.99)]
    bare = fuse_config(views, mesh, intr, VerdictConfig())
    boarded = fuse_config(views, mesh, intr, VerdictConfig(), bt)
    # without the board every face the view's rays reach is hot; with it the faces whose patches
    # touch the board (or neighbour one that does) are not, the wall farther out still is
    assert boarded.dirty.sum() < bare.dirty.sum() and boarded.dirty.any()
    near = np.isin(fp.cell, np.flatnonzero(np.bincount(fp.cell, fp.face == ON_BOARD, G * G) > 0))
    assert not boarded.dirty[np.unique(fp.face[near & (fp.face >= 0)])].any()
