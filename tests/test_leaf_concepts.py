"""The leaf modules behind one-definition-per-concept: images, surfaces, hashing (light, shared by all)."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.errors import CameraError, CellError, ClassifierError, PlanningError
from cellctl.hashing import bytes_sha256, file_sha256, file_sha256_or_none
from cellctl.images import IMAGE_MAGIC, decode_image, encode_image, image_format
from cellctl.surface import FACE_TAG, SURFACES, check_surface


def test_leaf_modules_import_nothing_heavy() -> None:
    code = (
        "import sys, cellctl.images, cellctl.surface, cellctl.hashing, cellctl.bus.topics, cellctl.geometry.camera\n"
        "print(sorted(m for m in ('cv2', 'torch', 'trimesh', 'zenoh', 'open3d', 'pybullet') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_decode_gives_rgb_or_bgr_from_the_same_bytes() -> None:
    rgb = np.zeros((20, 30, 3), np.uint8)
    rgb[..., 0] = 200  # red
    png = encode_image(rgb, "png")
    assert image_format(png) == "png" and png.startswith(IMAGE_MAGIC["png"])
    np.testing.assert_array_equal(decode_image(png), rgb)
    np.testing.assert_array_equal(decode_image(png, order="bgr"), rgb[..., ::-1])
    assert image_format(encode_image(rgb, "jpeg")) == "jpeg" and image_format(b"GIF89a") is None


def test_decode_normalises_grey_alpha_and_16_bit() -> None:
    grey = cv2.imencode(".png", np.full((32, 32), 90, np.uint8))[1].tobytes()
    assert decode_image(grey).shape == (32, 32, 3)
    rgba = cv2.imencode(".png", np.full((32, 32, 4), 7, np.uint8))[1].tobytes()
    assert decode_image(rgba).shape == (32, 32, 3)
    deep = cv2.imencode(".png", np.full((32, 32, 3), 0x1234, np.uint16))[1].tobytes()
    img = decode_image(deep)
    assert img.dtype == np.uint8 and int(img[0, 0, 0]) == 0x12


@pytest.mark.parametrize("error", [CameraError, ClassifierError])
def test_decode_raises_in_the_callers_family(error: type[CellError]) -> None:
    with pytest.raises(error, match=r"image from the camera \(png\) \(5 bytes, starts b'hello'\) cannot be decoded"):
        decode_image(b"hello", "from the camera (png)", error=error)
    with pytest.raises(error, match="is empty"):
        decode_image(b"", error=error)


def test_encode_refuses_an_unknown_format() -> None:
    with pytest.raises(CameraError, match="format 'gif' is unknown"):
        encode_image(np.zeros((16, 16, 3), np.uint8), "gif", CameraError)


def test_surfaces() -> None:
    assert SURFACES == ("external", "internal")
    assert FACE_TAG == {"external": 0, "internal": 1}
    assert check_surface("internal") == "internal"
    with pytest.raises(PlanningError, match=r"surface 'top' is unknown; expected one of \['external', 'internal'\]"):
        check_surface("top", PlanningError)
    with pytest.raises(CellError, match="start param surface 3 is unknown"):
        check_surface(3, what="start param surface")


def test_hashing_matches_hashlib(tmp_path: Path) -> None:
    data = np.random.default_rng(0).bytes(3 << 20)  # spans several 1 MiB blocks
    f = tmp_path / "blob.bin"
    f.write_bytes(data)
    assert file_sha256(f) == bytes_sha256(data) == hashlib.sha256(data).hexdigest()
    assert file_sha256_or_none(tmp_path / "missing") is None
    with pytest.raises(OSError):
        file_sha256(tmp_path / "missing")
