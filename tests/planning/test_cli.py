"""``cellctl plan --mesh``: a mesh that is not in the catalog plans too (JSON keys of the issue)."""

from __future__ import annotations

import json

from cellctl.cli import main
from cellctl.planning.shapes import open_box_bin


def test_plan_any_mesh_file_prints_the_issue_json(tmp_path, capsys):
    box = open_box_bin((0.8, 0.6, 0.8), max_edge=0.1)
    mesh_file = tmp_path / "box.stl"
    box.to_trimesh().export(mesh_file)
    out = tmp_path / "p.json"
    png = tmp_path / "p.png"
    rc = main(
        [
            "plan",
            "--mesh",
            str(mesh_file),
            "--base",
            "0 -0.95 -0.1 90",
            "--seed-pct",
            "3",
            "--json",
            "--out",
            str(out),
            "--png",
            str(png),
        ]
    )
    assert rc == 0
    j = json.loads(capsys.readouterr().out)
    assert set(j["counts"]) == {"generated", "filtered", "reachable", "greedy", "annealed", "optimal_cover"}
    assert set(j["area"]) >= {"mesh_m2", "visible_all_m2", "visible_selected_m2", "loss_pct"}
    assert set(j["times_s"]) >= {
        "generate_filter",
        "reachability",
        "visibility",
        "selection",
        "distance_matrix",
        "ordering",
        "total",
    }
    assert j["tour_cost"] > 0 and j["counts"]["annealed"] > 0
    assert out.is_file() and png.stat().st_size > 10_000


def test_bad_base_and_mm_mesh_are_clear_errors(tmp_path, capsys):
    box = open_box_bin((0.8, 0.6, 0.8), max_edge=0.2)
    mesh_file = tmp_path / "box_mm.stl"
    box.to_trimesh().apply_scale(1000.0).export(mesh_file)
    assert main(["plan", "--mesh", str(mesh_file), "--base", "0 -0.95 -0.1 90"]) == 2
    assert "millimetres" in capsys.readouterr().err
    assert main(["plan", "--mesh", str(mesh_file), "--base", "0 -0.95 90"]) == 2
    assert "X Y Z YAW_DEG" in capsys.readouterr().err
