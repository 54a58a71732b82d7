"""identify() on the twin's own camera images: every catalog bin from an observation pose."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.config import load_config
from cellctl.geometry.transforms import pose_error
from cellctl.sim import render as render_mod
from cellctl.sim import scene as scene_mod
from cellctl.vision import identify


@pytest.fixture(scope="module")
def twin():
    from cellctl.geometry.camera import CameraModel
    from cellctl.geometry.catalog import load_catalog

    cfg = load_config()
    try:
        cat = load_catalog(cfg.path(cfg.catalog))
    except Exception as err:  # the twin's meshes are generated assets
        pytest.skip(f"bin catalog not usable: {err}")
    return cat, render_mod.SimRenderer(cat), CameraModel.from_config(cfg.camera).intrinsics()


@pytest.mark.parametrize("index", [0])
def test_every_bin_identified_in_the_twin(twin, index) -> None:
    cat, renderer, intr = twin
    for bt in cat.names:
        T_bin_cam = scene_mod.observation_T_bin_cam(cat.get(bt), index)
        out = renderer.render_bin_view(bt, T_bin_cam, intr, dirty=False, seed=index)
        img = np.ascontiguousarray(out.rgb[..., ::-1])
        # Express the camera in the bin frame: then T_base_bin must come out as the identity.
        ident = identify(img, intr, T_bin_cam, cat)
        assert ident.bin_type == bt
        dt, dr = pose_error(np.eye(4), ident.T_base_bin)
        assert dt * 1000 < 3.0, f"{bt}: bin origin off by {dt * 1000:.2f} mm"
        assert np.degrees(dr) < 0.3, f"{bt}: rotation off by {np.degrees(dr):.3f} deg"


def test_twin_images_follow_the_opencv_pixel_convention(twin) -> None:
    """Corners detected in a twin frame sit where the pinhole model projects them (no half-pixel shift)."""
    from cellctl.geometry.transforms import invert
    from cellctl.vision.board import make_board
    from cellctl.vision.render import project, view_of_board

    cat, renderer, intr = twin
    bt = cat.names[0]
    spec = cat.get(bt).board
    T = view_of_board(spec, intr, 0.6, 20.0, 30.0)
    out = renderer.render_bin_view(bt, cat.get(bt).T_bin_board() @ invert(T), intr, dirty=False, seed=0)
    ident = identify(np.ascontiguousarray(out.rgb[..., ::-1]), intr, None, cat)
    truth = project(intr, T, make_board(spec).getChessboardCorners()[ident.corner_ids])
    mean = (ident.image_points - truth).mean(axis=0)
    assert np.all(np.abs(mean) < 0.15), f"mean corner offset {mean} px: renderer and intrinsics disagree"
