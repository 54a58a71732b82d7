"""Bin catalog: the committed catalog, frames, board ids, and every way a catalog can be wrong."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from cellctl.config import project_root
from cellctl.errors import ConfigError
from cellctl.geometry.bin_meshes import DESIGNS, build_mesh, paper_tag_T_bin
from cellctl.geometry.boards import board_image, make_charuco_board
from cellctl.geometry.catalog import T_tag_board, load_catalog, read_ply, write_ply
from cellctl.geometry.transforms import invert
from cellctl.hashing import file_sha256
from cellctl.surface import EXTERNAL, INTERNAL

ROOT = project_root()
CATALOG = ROOT / "config" / "bins.yaml"


@pytest.fixture(scope="module")
def catalog():
    return load_catalog(CATALOG)


def test_committed_catalog_has_three_distinct_bin_types(catalog) -> None:
    """Three types, 3,000–6,000 faces each, both surfaces tagged, mesh frame at the top opening."""
    assert set(catalog.names) == {"case_study", "drum", "tote"}
    for t in catalog:
        m = catalog.load_mesh(t.name)
        assert 3000 <= m.n_faces <= 6000, (t.name, m.n_faces)
        assert (m.surface == EXTERNAL).sum() > 1000 and (m.surface == INTERNAL).sum() > 1000
        assert abs(m.vertices[:, 2].max()) < 1e-9
        assert m.vertices[:, 2].min() == pytest.approx(-t.height_m, abs=1e-6)


def test_case_study_matches_the_paper(catalog) -> None:
    """1030 mm high, 880×740 footprint, board at Table 1 tag_H_bin."""
    t = catalog.get("case_study")
    m = catalog.load_mesh("case_study")
    ext = m.vertices.max(axis=0) - m.vertices.min(axis=0)
    assert ext == pytest.approx([0.88, 0.74, 1.03], abs=1e-6)
    tag = np.asarray(t.tag_T_bin)
    paper = np.array(
        [
            [0.9997, -0.0233, 0.0105, 0.0277],
            [-0.0095, 0.0391, 0.9992, 0.1491],
            [-0.0237, -0.999, 0.0388, -0.3838],
            [0, 0, 0, 1],
        ]
    )
    assert np.abs(tag - paper).max() < 1e-3
    assert np.abs(tag - paper_tag_T_bin()).max() < 1e-8
    # board = inv(tag_T_bin) · T_tag_board; the tag origin is the board's centre
    assert np.abs(t.T_bin_board() - invert(tag) @ T_tag_board(t.board)).max() < 1e-8
    w, h = t.board.size_m
    centre = t.T_bin_board() @ np.array([w / 2, h / 2, 0, 1])
    assert np.allclose(centre[:3], invert(tag)[:3, 3], atol=1e-9)
    # the board hangs on the -y wall, facing -y (its z axis points into the bin)
    assert t.T_bin_board()[1, 3] < -0.37 and t.T_bin_board()[:3, 2] @ [0, 1, 0] > 0.99


def test_marker_ids_identify_types(catalog) -> None:
    ranges = {t.name: t.board.ids for t in catalog}
    assert ranges["case_study"] == range(17)
    for name, ids in ranges.items():
        assert catalog.by_marker_id(ids.start).name == name
        assert catalog.by_marker_id(ids.stop - 1).name == name
    assert catalog.by_marker_id(999) is None


def test_board_image_carries_the_type_ids(catalog) -> None:
    """The rendered board texture holds exactly the type's marker ids (detected by OpenCV)."""
    import cv2

    t = catalog.get("drum")
    img = board_image(t.board, 60)
    assert img.shape == (5 * 60, 7 * 60)
    img = cv2.copyMakeBorder(img, 40, 40, 40, 40, cv2.BORDER_CONSTANT, value=255)
    board = make_charuco_board(t.board)
    det = cv2.aruco.ArucoDetector(board.getDictionary(), cv2.aruco.DetectorParameters())
    _, ids, _ = det.detectMarkers(img)
    assert sorted(ids.ravel().tolist()) == list(t.board.ids)


def test_ply_round_trip(tmp_path: Path) -> None:
    V, F, S = build_mesh(DESIGNS["tote"])
    p = tmp_path / "m.ply"
    write_ply(p, V, F, S)
    m = read_ply(p)
    assert np.allclose(m.vertices, V, atol=1e-6)
    assert np.array_equal(m.faces, F) and np.array_equal(m.surface, S)


def test_generator_reproduces_committed_meshes(tmp_path: Path) -> None:
    """`cellctl bins generate` is deterministic: same bytes, same sha256 as committed."""
    from cellctl.geometry.bin_meshes import generate_catalog

    path = generate_catalog(tmp_path)
    new = yaml.safe_load(path.read_text())["bins"]
    old = yaml.safe_load(CATALOG.read_text())["bins"]
    for name in old:
        assert new[name]["mesh_sha256"] == old[name]["mesh_sha256"] == file_sha256(ROOT / old[name]["mesh"])


def test_outer_faces_point_away_from_the_cavity() -> None:
    """External wall faces point outward, internal ones inward (renderer and planner rely on it)."""
    V, F, S = build_mesh(DESIGNS["case_study"])
    tri = V[F]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    c = tri.mean(axis=1)
    wall = (np.abs(n[:, 2]) < 1e-9 * np.linalg.norm(n, axis=1) + 1e-12) & (c[:, 2] > -0.45) & (c[:, 2] < -0.01)
    radial = np.einsum("ij,ij->i", n[:, :2], c[:, :2])
    assert (radial[wall & (S == EXTERNAL)] > 0).all()
    assert (radial[wall & (S == INTERNAL)] < 0).all()


# --- bad catalogs -----------------------------------------------------------------------------


def _copy_catalog(tmp_path: Path) -> tuple[Path, dict]:
    (tmp_path / "config").mkdir()
    shutil.copytree(ROOT / "models" / "bins", tmp_path / "models" / "bins")
    data = yaml.safe_load(CATALOG.read_text())
    return tmp_path / "config" / "bins.yaml", data


def _write(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_overlapping_board_ids_are_rejected(tmp_path: Path) -> None:
    path, data = _copy_catalog(tmp_path)
    data["bins"]["drum"]["board"]["first_id"] = 10
    with pytest.raises(ConfigError, match=r"overlap.*'case_study' uses 0..16 and 'drum' uses 10..26"):
        load_catalog(_write(path, data))


def test_missing_mesh_is_named(tmp_path: Path) -> None:
    path, data = _copy_catalog(tmp_path)
    (tmp_path / "models" / "bins" / "tote.ply").unlink()
    with pytest.raises(ConfigError, match=r"bin 'tote': mesh file .*tote.ply' does not exist"):
        load_catalog(_write(path, data))


def test_sha_mismatch_names_both_hashes(tmp_path: Path) -> None:
    path, data = _copy_catalog(tmp_path)
    mesh = tmp_path / "models" / "bins" / "drum.ply"
    mesh.write_text(mesh.read_text() + "\n")
    with pytest.raises(ConfigError, match=r"bin 'drum': mesh .* has sha256 [0-9a-f]{64}, catalog expects 9ee2"):
        load_catalog(_write(path, data))


def test_mesh_outside_the_frame_convention_is_rejected(tmp_path: Path) -> None:
    path, data = _copy_catalog(tmp_path)
    V, F, S = build_mesh(DESIGNS["drum"])
    mesh = tmp_path / "models" / "bins" / "drum.ply"
    write_ply(mesh, V + [0.0, 0.0, 0.85], F, S)  # origin at the bottom instead of the top opening
    data["bins"]["drum"]["mesh_sha256"] = file_sha256(mesh)
    cat = load_catalog(_write(path, data))
    with pytest.raises(ConfigError, match=r"mesh top is at z = 0.850 m; expected ~0"):
        cat.load_mesh("drum")


def test_corrupt_mesh_is_rejected(tmp_path: Path) -> None:
    path, data = _copy_catalog(tmp_path)
    mesh = tmp_path / "models" / "bins" / "tote.ply"
    mesh.write_text("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n0 0\n")
    data["bins"]["tote"]["mesh_sha256"] = file_sha256(mesh)
    cat = load_catalog(_write(path, data))
    with pytest.raises(ConfigError, match="tote.ply"):
        cat.load_mesh("tote")


def test_unknown_key_and_unknown_type(tmp_path: Path, catalog) -> None:
    path, data = _copy_catalog(tmp_path)
    data["bins"]["drum"]["colour"] = "red"
    with pytest.raises(ConfigError, match="unknown key 'colour'"):
        load_catalog(_write(path, data))
    with pytest.raises(
        ConfigError, match=r"bin type 'crate' is unknown; the catalog has \['case_study', 'drum', 'tote'\]"
    ):
        catalog.get("crate")


def test_inconsistent_tag_and_board_are_rejected(tmp_path: Path) -> None:
    path, data = _copy_catalog(tmp_path)
    data["bins"]["case_study"]["board"]["T_bin_board"][0][3] += 0.05
    with pytest.raises(ConfigError, match="T_bin_board disagrees with inv\\(tag_T_bin\\)"):
        load_catalog(_write(path, data))


def test_any_mesh_format_following_the_frame_convention_is_accepted(tmp_path: Path) -> None:
    """An OBJ bin (no tags in the file) with a sidecar of surface tags loads like the PLY ones."""
    import trimesh

    path, data = _copy_catalog(tmp_path)
    V, F, S = build_mesh(DESIGNS["drum"])
    obj = tmp_path / "models" / "bins" / "drum2.obj"
    trimesh.Trimesh(V, F, process=False).export(obj)
    np.save(obj.with_suffix(".obj.surface.npy"), S)
    entry = dict(data["bins"]["drum"], mesh="models/bins/drum2.obj", mesh_sha256=file_sha256(obj))
    entry["board"] = dict(entry["board"], first_id=51)
    data["bins"]["drum2"] = entry
    cat = load_catalog(_write(path, data))
    m = cat.load_mesh("drum2")
    assert m.n_faces == len(F) and np.array_equal(m.surface, S)
    assert cat.by_marker_id(60).name == "drum2"
