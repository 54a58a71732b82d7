"""`cellctl identify` on files and the pose-bench measurement core."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import yaml

from cellctl.bench.pose import measure
from cellctl.cli import main
from cellctl.cli.vision import parse_camera_pose, parse_intrinsics
from cellctl.errors import CellError
from cellctl.geometry.transforms import pose_error, transform_from_pose
from cellctl.vision.render import render_boards, view_of_board

from .scenes import INTR, SPEC_B, T_BIN_BOARD


@pytest.fixture
def catalog_file(tmp_path):
    """A bins.yaml in the twin's catalog format holding SPEC_B."""
    bins = tmp_path / "bins.yaml"
    bins.write_text(
        yaml.safe_dump(
            {
                "bins": {
                    "tall_bin": {
                        "mesh": "models/bins/none.ply",
                        "mesh_sha256": "0" * 64,
                        "height_m": 1.0,
                        "top_hole_radius_m": 0.25,
                        "board": {
                            "squares_x": 7,
                            "squares_y": 5,
                            "square_m": 0.06,
                            "marker_m": 0.045,
                            "first_id": 17,
                            "T_bin_board": T_BIN_BOARD.tolist(),
                        },
                    }
                }
            }
        )
    )
    return bins


def test_identify_cli_json_and_draw(tmp_path, catalog_file, capsys) -> None:
    T = view_of_board(SPEC_B, INTR, 0.9, 25.0, 45.0)
    img_path = tmp_path / "view.png"
    cv2.imwrite(str(img_path), render_boards([(SPEC_B, T)], INTR, rng=np.random.default_rng(0)))
    pose = "0.5 0.1 1.2 0.0 0.0 0.7071068 0.7071068"
    draw = tmp_path / "drawn.png"
    rc = main(
        [
            "identify",
            str(img_path),
            "--intrinsics",
            f"{INTR.fx},{INTR.fy},{INTR.cx},{INTR.cy}",
            "--camera-pose",
            pose,
            "--json",
            "--catalog",
            str(catalog_file),
            "--draw",
            str(draw),
        ]
    )
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    assert d["identified"] and d["bin_type"] == "tall_bin" and d["n_corners"] == 24
    T_base_cam = parse_camera_pose(pose)
    T_true = T_base_cam @ T @ np.linalg.inv(T_BIN_BOARD)
    est = transform_from_pose((d["T_base_bin"]["position"], d["T_base_bin"]["orientation"]))
    dt, dr = pose_error(T_true, est)
    assert dt < 0.003 and np.degrees(dr) < 0.2
    assert cv2.imread(str(draw)).shape == (720, 1280, 3)


def test_identify_cli_not_identified(tmp_path, catalog_file, capsys) -> None:
    img_path = tmp_path / "blank.png"
    cv2.imwrite(str(img_path), np.full((720, 1280, 3), 80, np.uint8))
    rc = main(
        [
            "identify",
            str(img_path),
            "--intrinsics",
            f"{INTR.fx},{INTR.fy},{INTR.cx},{INTR.cy}",
            "--json",
            "--catalog",
            str(catalog_file),
        ]
    )
    assert rc == 1
    d = json.loads(capsys.readouterr().out)
    assert d == {"identified": False, "code": "no markers", "reason": d["reason"]} and "no markers" in d["reason"]
    rc = main(["identify", str(img_path), "--intrinsics", "910,910,640,360", "--catalog", str(catalog_file)])
    assert rc == 2 and "no markers detected" in capsys.readouterr().err


def test_cli_argument_parsing(tmp_path) -> None:
    k = parse_intrinsics("900, 905, 641.5, 359", 1280, 720)
    assert (k.fx, k.fy, k.cx, k.cy, k.width) == (900, 905, 641.5, 359, 1280)
    f = tmp_path / "intr.json"
    f.write_text(
        json.dumps({"intrinsics": {"fx": 911.0, "fy": 912.0, "cx": 640.0, "cy": 360.0, "dist": [0.01, 0, 0, 0, 0]}})
    )
    assert parse_intrinsics(str(f), 1280, 720).dist[0] == 0.01
    with pytest.raises(CellError, match="neither an existing file nor four numbers"):
        parse_intrinsics("910,910", 1280, 720)
    with pytest.raises(CellError, match="expected 7 numbers"):
        parse_camera_pose("1 2 3")
    with pytest.raises(CellError, match="is not a rotation"):
        parse_camera_pose("1 2 3 0 0 0 0")
    np.testing.assert_allclose(parse_camera_pose(None), np.eye(4))


def test_bench_measure_core() -> None:
    out = measure(SPEC_B, INTR, n=3, seed=1, distances=(1.0,), progress=False)
    row = out["distances"][0]
    assert row["n"] == 3 and row["identified"] == 3
    assert row["trans_mm"]["p95"] < 2.0 and row["rot_deg"]["p95"] < 0.3
    f = out["focal_error_0_5pct"]["distances"][0]
    # A 0.5 % focal error moves the board ~0.5 % of its distance along the ray (~5 mm at 1 m).
    assert 3.0 < f["trans_mm"]["p50"] < 7.0
    assert out["ms_per_identification"] > 0
    fused = out["fused_3_views"]["distances"][0]
    assert fused["n"] == 1 and fused["identified"] == 1
    assert fused["trans_mm"]["p50"] < 2.0 and fused["rot_deg"]["p50"] < 0.3


def test_calibrate_intrinsics_cli(tmp_path, catalog_file, capsys) -> None:
    rng = np.random.default_rng(3)
    imgs = tmp_path / "views"
    imgs.mkdir()
    for k in range(8):
        T = view_of_board(
            SPEC_B,
            INTR,
            rng.uniform(0.55, 0.8),
            rng.uniform(25, 45),
            45.0 * k,
            offset_px=(rng.uniform(-200, 200), rng.uniform(-100, 100)),
        )
        cv2.imwrite(str(imgs / f"v{k}.png"), render_boards([(SPEC_B, T)], INTR, rng=rng))
    out = tmp_path / "intr.json"
    rc = main(["calibrate", "intrinsics", "--images", str(imgs), "--catalog", str(catalog_file), "--out", str(out)])
    assert rc == 0
    data = json.loads(out.read_text())
    assert data["type"] == "cellctl/IntrinsicsCalibration" and len(data["views"]) == 8
    assert abs(data["intrinsics"]["fx"] / INTR.fx - 1) < 0.003
    assert "camera: {fx: " in capsys.readouterr().err
    # The file feeds `cellctl identify --intrinsics FILE` directly.
    assert parse_intrinsics(str(out), 1280, 720).fx == data["intrinsics"]["fx"]
