"""`cellctl sim render`, `cellctl bins list`, `cellctl bench sim` from the command line."""

from __future__ import annotations

from pathlib import Path

import cv2
import pytest

from cellctl.cli import main


def test_bins_list_prints_every_type(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bins", "list"]) == 0
    out = capsys.readouterr().out
    for name, ids in (("case_study", "0..16"), ("drum", "17..33"), ("tote", "34..50")):
        line = next(ln for ln in out.splitlines() if ln.startswith(name))
        assert ids in line and len(line.split()[-1]) == 64


def test_sim_render_writes_a_picture(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "drum.png"
    assert (
        main(
            [
                "sim",
                "render",
                "--bin",
                "drum",
                "--dirty",
                "--width",
                "160",
                "--height",
                "90",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    img = cv2.imread(str(out))
    assert img.shape == (90, 160, 3)
    assert "drum (dirty)" in capsys.readouterr().err


def test_sim_render_unknown_bin_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sim", "render", "--bin", "crate", "--out", str(tmp_path / "x.png")]) == 2
    assert "bin type 'crate' is unknown" in capsys.readouterr().err


@pytest.mark.slow
def test_bench_sim_reports_the_three_figures() -> None:
    from cellctl.bench.options import BenchOptions
    from cellctl.bench.sim import bench_sim

    r = bench_sim(BenchOptions(n=200, seed=0))
    assert r["ik_fk_roundtrip_max_m"] < 1e-6
    for k in ("ik_us_per_pose", "collision_us_per_config", "render_ms_1280x720"):
        assert r[k] > 0
