"""calibrate_intrinsics(): recovers the focal length and principal point from rendered board views."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cellctl.errors import CellError
from cellctl.vision.intrinsics import calibrate_intrinsics, load_images
from cellctl.vision.render import render_boards, view_of_board

from .scenes import INTR, SPEC_A, SPEC_B


def _views(n: int, seed: int) -> list[tuple[str, np.ndarray]]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        spec = SPEC_A if k % 2 else SPEC_B  # any catalog board may be used
        T = view_of_board(
            spec,
            INTR,
            rng.uniform(0.55, 0.9),
            rng.uniform(25, 45),
            360.0 * k / n,
            roll_deg=rng.uniform(-20, 20),
            offset_px=(rng.uniform(-250, 250), rng.uniform(-120, 120)),
        )
        out.append((f"view{k:02d}.png", render_boards([(spec, T)], INTR, rng=rng)))
    return out


def test_recovers_intrinsics(catalog) -> None:
    res = calibrate_intrinsics(_views(12, 0), catalog)
    k = res.intrinsics
    assert abs(k.fx / INTR.fx - 1) < 0.002 and abs(k.fy / INTR.fy - 1) < 0.002
    assert abs(k.cx - INTR.cx) < 2.0 and abs(k.cy - INTR.cy) < 2.0
    assert abs(k.dist[0]) < 0.02
    assert res.rms_px < 0.3 and len(res.per_view_rms_px) == 12
    assert 0 < res.std_fx < 2.0
    assert res.to_dict()["fx_rel_std_pct"] < 0.2


def test_too_few_views_says_why(catalog, tmp_path) -> None:
    views = _views(3, 1) + [("blank.png", np.full((720, 1280, 3), 90, np.uint8))]
    for name, img in views:
        cv2.imwrite(str(tmp_path / name), img)
    loaded = load_images(tmp_path)
    assert [n for n, _ in loaded] == ["blank.png", "view00.png", "view01.png", "view02.png"]
    with pytest.raises(CellError, match=r"needs ≥ 6 usable board views, got 3; skipped: \['blank.png: no markers"):
        calibrate_intrinsics(loaded, catalog)


def test_mixed_sizes_and_empty_folder(catalog, tmp_path) -> None:
    views = _views(1, 2) + [("small.png", np.zeros((480, 640), np.uint8))]
    with pytest.raises(CellError, match="is 640×480 px; the first image was 1280×720 px"):
        calibrate_intrinsics(views, catalog)
    with pytest.raises(CellError, match="holds no readable images"):
        load_images(tmp_path)
    with pytest.raises(CellError, match="does not exist"):
        load_images(tmp_path / "nope")
