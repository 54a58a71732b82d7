"""The one camera model (from config, scaled, on the wire) and the one look_at (incl. its degenerate case)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cellctl.config import load_config
from cellctl.errors import CellError, ConfigError
from cellctl.geometry.camera import D435_COLOR, CameraModel
from cellctl.geometry.transforms import check_transform, look_at


def test_d435_default_is_920px_with_the_d435_field_of_view() -> None:
    assert (D435_COLOR.width, D435_COLOR.height, D435_COLOR.fx, D435_COLOR.fy) == (1280, 720, 920.0, 920.0)
    h, v = D435_COLOR.fov_deg
    assert h == pytest.approx(69.65, abs=0.01) and v == pytest.approx(42.74, abs=0.01)


def test_from_config_scales_the_default_to_the_configured_resolution() -> None:
    """The default config's camera is the D435 model; a 640x360 twin keeps its field of view."""
    assert CameraModel.from_config(load_config().camera) == D435_COLOR
    small = CameraModel.from_config(load_config(None, ["camera.width=640", "camera.height=360"]).camera)
    assert (small.width, small.fx, small.cx, small.cy) == (640, 460.0, 320.0, 180.0)
    assert small.fov_deg == pytest.approx(D435_COLOR.fov_deg)
    assert small == D435_COLOR.scaled(0.5)


def test_from_config_takes_calibrated_values() -> None:
    cfg = load_config(None, ["camera.fx=905.5", "camera.cx=641.25"])
    m = CameraModel.from_config(cfg.camera)
    assert (m.fx, m.fy, m.cx, m.cy) == (905.5, 905.5, 641.25, 360.0)


def test_wire_round_trip_and_json() -> None:
    m = dataclasses.replace(D435_COLOR, dist=(0.1, -0.02, 0.0, 0.0, 0.001))
    intr = m.intrinsics()
    assert intr.dist == [0.1, -0.02, 0.0, 0.0, 0.001]
    assert CameraModel.from_intrinsics(intr) == m
    np.testing.assert_array_equal(intr.K(), m.K())
    assert CameraModel(**m.to_json()) == m  # plan files hold lists; the model normalises them


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"fx": 0.0}, "fx=0.0, fy=920.0 must be positive"),
        ({"width": 0}, "size 0×720 must be positive whole pixels"),
        ({"fx": "wide"}, "fx 'wide' is not a number"),
        ({"dov": (0.6, 0.2)}, r"depth of view \[0.6, 0.2\]"),
        ({"cy": float("inf")}, "non-finite"),
    ],
)
def test_bad_camera_values_are_refused_by_name(kw: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        CameraModel(**kw)


def test_look_at_points_z_at_the_target_with_image_up_toward_up() -> None:
    eye, target = np.array([1.0, -0.5, 0.8]), np.array([0.0, 0.2, 0.1])
    T = check_transform(look_at(eye, target), "look_at")
    z = (target - eye) / np.linalg.norm(target - eye)
    np.testing.assert_allclose(T[:3, 2], z, atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], eye)
    assert T[:3, 0] @ [0, 0, 1] == pytest.approx(0.0, abs=1e-12)  # image x stays horizontal
    assert T[:3, 1] @ [0, 0, 1] < 0  # image y (down) points away from world up


def test_look_at_degenerate_case_is_a_map_seen_from_above() -> None:
    """Eye→target parallel to up: image x = world +X, image y = world −Y (documented fall-back)."""
    down = look_at([0.3, 0.2, 1.0], [0.3, 0.2, 0.0])
    np.testing.assert_allclose(down[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    up = look_at([0.0, 0.0, 0.0], [0.0, 0.0, 2.0])  # anti-parallel case: still a proper rotation
    check_transform(up, "looking up")
    np.testing.assert_allclose(up[:3, 2], [0, 0, 1], atol=1e-12)
    # up along Y and looking along Y: the Y helper is useless too, X takes over
    along_y = look_at([0.0, 0.0, 0.0], [0.0, 1.0, 0.0], up=(0.0, 1.0, 0.0))
    check_transform(along_y, "looking along Y")
    np.testing.assert_allclose(along_y[:3, 2], [0, 1, 0], atol=1e-12)


def test_look_at_roll_turns_the_image_about_the_optical_axis() -> None:
    T0 = look_at([1.0, 0.0, 0.5], [0.0, 0.0, 0.0])
    T1 = look_at([1.0, 0.0, 0.5], [0.0, 0.0, 0.0], roll_rad=np.pi / 2)
    np.testing.assert_allclose(T1[:3, 2], T0[:3, 2], atol=1e-12)
    np.testing.assert_allclose(T1[:3, 0], T0[:3, 1], atol=1e-12)  # x turned onto the old y


@pytest.mark.parametrize(
    ("eye", "target", "up", "match"),
    [
        ((1, 2, 3), (1, 2, 3), (0, 0, 1), "coincide"),
        ((0, 0, 1), (0, 0, 0), (0, 0, 0), "zero vector"),
        ((0, 0, float("nan")), (0, 0, 0), (0, 0, 1), "finite"),
    ],
)
def test_look_at_refuses_what_has_no_view(eye, target, up, match: str) -> None:
    with pytest.raises(CellError, match=match):
        look_at(eye, target, up)
