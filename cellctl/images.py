"""Encoded images on the bus and on disk: limits, signatures, the one encoder and decoder.

Camera captures travel as PNG or JPEG bytes (a query payload), are recorded as such in
MCAP logs, stored as PNG in datasets and decoded by the identifier (BGR, OpenCV's order)
and the classifier (RGB). Every one of those paths uses the functions here, so a grey,
16-bit or RGBA file, an empty payload or a 20 000-px image is treated the same everywhere.

Light module: numpy at import, OpenCV only inside :func:`encode_image`/:func:`decode_image`
(the daemon decodes images for identification, but importing this module stays cheap).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import NDArray

from cellctl.errors import CellError

__all__ = [
    "IMAGE_MAGIC",
    "MAX_IMAGE_BYTES",
    "MAX_IMAGE_PIXELS",
    "MAX_IMAGE_SIDE",
    "MIN_IMAGE_SIDE",
    "ImageFormat",
    "check_budget",
    "decode_image",
    "encode_image",
    "image_format",
    "image_size",
]

ImageFormat = Literal["png", "jpeg"]
"""An encoded image's format, as wire messages name it."""

MAX_IMAGE_BYTES = 32 * 1024 * 1024
"""Largest encoded image a worker accepts as a query payload (a 1280×720 PNG is ~1–2 MB)."""
MAX_IMAGE_SIDE = 8192
"""Largest accepted image side in pixels (a bigger one is refused, not resized)."""
MAX_IMAGE_PIXELS = 4096 * 4096
"""Default pixel budget (width × height) checked from the header before decoding: 16.8 Mpx, 18×
the 1280×720 camera, ~50 MB decoded. A 20000×20000 PNG is ~1 MB on disk but 1.2 GB decoded."""
MIN_IMAGE_SIDE = 16
"""Smallest accepted image side in pixels: below this there is nothing to identify or classify."""

IMAGE_MAGIC: dict[ImageFormat, bytes] = {"png": b"\x89PNG\r\n\x1a\n", "jpeg": b"\xff\xd8\xff"}
"""The leading bytes of each format (a signature check, not a decode)."""


def image_format(data: bytes) -> ImageFormat | None:
    """The format whose signature ``data`` starts with, or None."""
    for fmt, magic in IMAGE_MAGIC.items():
        if data.startswith(magic):
            return fmt
    return None


def image_size(data: bytes, source: str = "<bytes>", error: type[CellError] = CellError) -> tuple[int, int]:
    """``(width, height)`` read from a PNG's IHDR or a JPEG's SOF header, without decoding pixels.

    Also refuses a file that cannot be whole: a PNG without its closing IEND chunk, a JPEG without its
    EOI marker (libjpeg would otherwise hand back a half-grey image with only a warning on stderr).

    Raises:
        error: not PNG/JPEG, or a missing/short header, or a truncated file.
    """
    fmt = image_format(data)
    what = f"image {source} ({len(data)} bytes, starts {bytes(data[:8])!r})"
    if fmt == "png":
        size = _png_size(data)
        whole = data.rstrip(b"\0").endswith(b"IEND\xaeB`\x82")
    elif fmt == "jpeg":
        size = _jpeg_size(data)
        whole = data.rstrip(b"\0").endswith(b"\xff\xd9")
    else:
        raise error(f"{what} cannot be decoded; expected PNG or JPEG")
    if size is None:
        raise error(f"{what} cannot be decoded: its {fmt} header (size) is missing or damaged")
    if not whole:
        raise error(f"{what} cannot be decoded: the {fmt} file is truncated (no end marker)")
    return size


def _png_size(data: bytes) -> tuple[int, int] | None:
    # IHDR must be the first chunk: length 13, then width and height as big-endian uint32.
    if len(data) < 24 or data[12:16] != b"IHDR":
        return None
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


# Start-of-frame markers carry the size; C4 (DHT), C8 (JPG) and CC (DAC) share the range but do not.
_JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    i = 2
    while i + 4 <= len(data):  # each step moves forward: bounded by the length
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):  # markers without a length
            i += 2
            continue
        if marker in (0xD9, 0xDA):  # end of image / start of scan before any frame header
            return None
        length = int.from_bytes(data[i + 2 : i + 4], "big")
        if length < 2:
            return None
        if marker in _JPEG_SOF:
            if i + 9 > len(data):
                return None
            return int.from_bytes(data[i + 7 : i + 9], "big"), int.from_bytes(data[i + 5 : i + 7], "big")
        i += 2 + length
    return None


def encode_image(rgb: NDArray[np.uint8], fmt: str, error: type[CellError] = CellError) -> bytes:
    """Encode an RGB ``(H, W, 3)`` uint8 image as PNG or JPEG bytes.

    Raises:
        error: unknown format or the encoder failed.
    """
    import cv2

    ext = {"png": ".png", "jpeg": ".jpg"}.get(fmt)
    if ext is None:
        raise error(f"image format {fmt!r} is unknown; expected 'png' or 'jpeg'")
    ok, buf = cv2.imencode(ext, np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise error(f"cannot encode a {rgb.shape} image as {fmt}")
    return buf.tobytes()


def check_budget(
    data: bytes, source: str = "<bytes>", error: type[CellError] = CellError, max_pixels: int = MAX_IMAGE_PIXELS
) -> tuple[int, int]:
    """``(width, height)`` from the header, checked against the pixel budget before anything decodes it.

    The one check of every path that decodes an image, or that stores one for a later decode.

    Raises:
        error: no readable PNG/JPEG header, more than ``max_pixels`` pixels, or a side over
            :data:`MAX_IMAGE_SIDE`.
    """
    w, h = image_size(data, source, error)
    if w * h > max_pixels or max(w, h) > MAX_IMAGE_SIDE:
        raise error(
            f"image {source} is {w}×{h} px ({w * h} px) by its header; the budget is {max_pixels} px with sides "
            f"up to {MAX_IMAGE_SIDE} px (camera.max_image_pixels); refused before decoding"
        )
    return w, h


def decode_image(
    data: bytes,
    source: str = "<bytes>",
    *,
    order: Literal["rgb", "bgr"] = "rgb",
    error: type[CellError] = CellError,
    max_pixels: int = MAX_IMAGE_PIXELS,
) -> NDArray[np.uint8]:
    """Decode PNG/JPEG bytes to a uint8 ``(H, W, 3)`` array.

    Grey images are expanded to three channels, an alpha channel is dropped and 16-bit
    images keep their high byte, so every caller gets the same 8-bit colour array.

    Args:
        data: the encoded bytes.
        source: how messages name the image (a file path, "(png, 1234 bytes)").
        order: channel order of the result: ``rgb`` (classifier, datasets) or ``bgr``
            (OpenCV's, the identifier's).
        error: the exception class to raise (the caller's family: CameraError, ClassifierError).
        max_pixels: pixel budget (width × height), checked from the header before any pixel is
            decoded, so a decompression bomb costs microseconds (``camera.max_image_pixels``).

    Raises:
        error: empty, truncated or undecodable bytes, more than ``max_pixels`` pixels, or sides
            outside [:data:`MIN_IMAGE_SIDE`, :data:`MAX_IMAGE_SIDE`].
    """
    import cv2

    if not data:
        raise error(f"image {source} is empty (0 bytes); expected PNG or JPEG bytes")
    check_budget(data, source, error, max_pixels)
    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise error(
            f"image {source} ({len(data)} bytes, starts {bytes(data[:8])!r}) cannot be decoded; expected PNG or JPEG"
        )
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    if img.dtype != np.uint8:
        raise error(f"image {source} has dtype {img.dtype}; expected 8-bit")
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    if img.ndim != 3 or img.shape[2] != 3:
        raise error(f"image {source} has shape {img.shape}; expected H×W×3 colour (or grey/RGBA)")
    h, w = img.shape[:2]
    if min(h, w) < MIN_IMAGE_SIDE or max(h, w) > MAX_IMAGE_SIDE:
        raise error(f"image {source} is {w}×{h} px; expected sides between {MIN_IMAGE_SIDE} and {MAX_IMAGE_SIDE} px")
    if order == "rgb":
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return np.ascontiguousarray(img)
