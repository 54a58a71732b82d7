"""Pure-array stages: eq. 1-2 viewpoints, seeds, filters, mesh checks."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.errors import PlanningError
from cellctl.planning.collision import PlanningWorld
from cellctl.planning.filters import camera_collision_filter, distance_filter, height_filter, occlusion_filter
from cellctl.planning.mesh import infer_surface_tags, load_bin_mesh, mesh_from_arrays
from cellctl.planning.raycast import RayCaster
from cellctl.planning.seeds import sample_seeds
from cellctl.planning.viewpoints import Viewpoints, generate_viewpoints, rotation_z_to


def test_rotation_z_to_maps_z_onto_k_including_minus_z():
    """Eq. 1 gives proper rotations with R·Z = k, also at the singular k = −Z."""
    rng = np.random.default_rng(0)
    k = rng.normal(size=(50, 3))
    k = np.vstack([k, [[0, 0, -1.0], [0, 0, 1.0]]])
    k /= np.linalg.norm(k, axis=1, keepdims=True)
    R = rotation_z_to(k)
    assert np.allclose(R[:, :, 2], k, atol=1e-9)
    assert np.allclose(R @ R.transpose(0, 2, 1), np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(R), 1.0)


def test_external_viewpoints_look_along_minus_normal_at_each_distance():
    pts = np.array([[0.1, 0.2, -0.3], [0.0, 0.0, -0.8]])
    nrm = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    vp = generate_viewpoints(pts, nrm, np.array([5, 7]), "external", (0.3, 0.4))
    assert len(vp) == 4
    assert vp.rank.tolist() == [0, 1, 0, 1] and vp.seed.tolist() == [0, 0, 1, 1]
    assert np.allclose(vp.T[:, :3, 2], -nrm[vp.seed])
    d = np.linalg.norm(vp.T[:, :3, 3] - pts[vp.seed], axis=1)
    assert np.allclose(d, [0.3, 0.4, 0.3, 0.4])
    assert vp.seed_face.tolist() == [5, 5, 7, 7]


def test_internal_viewpoints_radiate_from_the_origin():
    pts = np.array([[0.2, 0.0, -0.5], [-0.1, 0.25, -0.2]])
    vp = generate_viewpoints(pts, np.zeros((2, 3)) + [0, 0, 1], np.array([0, 1]), "internal", (0.3,))
    k = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    assert np.allclose(vp.T[:, :3, 2], k)
    # origins lie on the ray from O through the seed
    o = vp.T[:, :3, 3]
    assert np.allclose(np.cross(o, k), 0.0, atol=1e-12)


def test_bad_distances_and_surface_are_refused():
    with pytest.raises(PlanningError, match="positive"):
        generate_viewpoints(np.zeros((1, 3)), np.ones((1, 3)), np.zeros(1, int), "external", (0.3, -0.1))
    with pytest.raises(PlanningError, match="'top'"):
        generate_viewpoints(np.zeros((1, 3)), np.ones((1, 3)), np.zeros(1, int), "top", (0.3,))


def test_seeds_count_lie_on_their_faces_and_surface(box):
    rng = np.random.default_rng(0)
    pts, faces = sample_seeds(box, "external", 10.0, rng)
    n_ext = int((~box.internal).sum())
    assert len(pts) == round(0.1 * n_ext)
    assert not box.internal[faces].any()
    # each seed lies in its face's plane
    d = np.einsum("ij,ij->i", pts - box.centroids[faces], box.normals[faces])
    assert np.abs(d).max() < 1e-9
    with pytest.raises(PlanningError, match="seed percentage 0"):
        sample_seeds(box, "external", 0, rng)


def test_filters_height_distance_occlusion_camera(box, robot, T_bin_base):
    # four hand-made viewpoints on the -y outer wall (normal -y)
    s = np.array([[0.0, -0.3, -0.4]] * 4)
    vp = generate_viewpoints(s, np.array([[0, -1.0, 0]] * 4), np.zeros(4, int), "external", (0.3,))
    T = vp.T.copy()
    T[1, 2, 3] = -3.0  # far below the floor
    T[2, :3, 3] = [0.0, 0.2, -0.4]  # inside the box, behind the inner +y wall: occluded
    T[3, :3, 3] = [0.0, -0.29, -0.4]  # optical centre inside the wall: the camera body hits it
    d = np.linalg.norm(box.centroids - s[0], axis=1) + 10.0 * box.internal
    seed_face = np.full(4, int(np.argmin(d)))
    vp = Viewpoints(T, vp.seed, vp.rank, seed_face, vp.seed_point)
    assert height_filter(vp, box, 0.1).tolist() == [True, False, True, True]
    assert distance_filter(vp, T_bin_base[:3, 3], 1.3).tolist() == [True, False, True, True]
    occ = occlusion_filter(vp, box, RayCaster(box.vertices, box.faces))
    assert occ[0] and not occ[2]
    cam = camera_collision_filter(vp, PlanningWorld(box, robot, T_bin_base))
    assert cam[0] and not cam[3]


def test_mesh_in_millimetres_is_refused(box):
    with pytest.raises(PlanningError, match="millimetres"):
        mesh_from_arrays(box.vertices * 1000.0, box.faces, name="mm_bin")


def test_zero_area_faces_are_dropped_and_all_degenerate_is_an_error(box):
    V = np.vstack([box.vertices, box.vertices[:1]])
    F = np.vstack([box.faces, [[0, 1, 1]], [[0, len(V) - 1, 0]]])
    m = mesh_from_arrays(V, F, name="with_slivers")
    assert len(m.faces) == len(box.faces)
    with pytest.raises(PlanningError, match="zero area"):
        mesh_from_arrays(np.array([[0, 0, 0], [0.5, 0, 0], [1.0, 0, 0]]), np.array([[0, 1, 2]]), name="line")


def test_non_watertight_is_flagged_or_refused(box):
    m = mesh_from_arrays(box.vertices, box.faces[:-10], name="holey")
    assert not m.watertight
    with pytest.raises(PlanningError, match="not watertight"):
        mesh_from_arrays(box.vertices, box.faces[:-10], name="holey", require_watertight=True)


def test_missing_and_unreadable_mesh_files(tmp_path):
    with pytest.raises(PlanningError, match="does not exist"):
        load_bin_mesh(tmp_path / "nope.stl")
    bad = tmp_path / "bad.stl"
    bad.write_bytes(b"solid x\nthis is not an stl\n")
    with pytest.raises(PlanningError, match=str(bad.name)):
        load_bin_mesh(bad)


def test_surface_tags_are_inferred_for_untagged_meshes(box):
    assert (infer_surface_tags(box) == box.internal).mean() > 0.99
