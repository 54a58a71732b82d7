"""Hostile images built in memory: a real decompression-bomb PNG and truncations of good files."""

from __future__ import annotations

import struct
import zlib

__all__ = ["jpeg_claiming", "png_bomb", "png_claiming"]


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_bomb(width: int = 20000, height: int = 20000, rows_per_block: int = 100) -> bytes:
    """A valid 8-bit RGB PNG of ``width``×``height`` black pixels (20000² → ~1.2 MB, 1.2 GB decoded).

    Deflating 1.2 GB of zeros takes seconds, so one block of ``rows_per_block`` rows is deflated once,
    ended with a full flush (which resets the compressor's history, making every later block the same
    bytes) and repeated; the stream's Adler-32 is computed for the whole (all-zero) image. ``height``
    must be a multiple of ``rows_per_block``.
    """
    assert height % rows_per_block == 0, (height, rows_per_block)
    raw_rows = (b"\0" * (1 + 3 * width)) * rows_per_block  # filter byte 0 + RGB zeros
    comp = zlib.compressobj(9)
    first = comp.compress(raw_rows) + comp.flush(zlib.Z_FULL_FLUSH)
    again = comp.compress(raw_rows) + comp.flush(zlib.Z_FULL_FLUSH)
    tail = comp.flush(zlib.Z_FINISH)[:-4]  # the final empty block, without the partial checksum
    total = (1 + 3 * width) * height
    adler = (total % 65521) << 16 | 1  # Adler-32 of `total` zero bytes: a = 1, b = total mod 65521
    body = first + again * (height // rows_per_block - 1) + tail + struct.pack(">I", adler)
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", body) + _chunk(b"IEND", b"")


def png_claiming(width: int, height: int) -> bytes:
    """A PNG whose IHDR claims ``width``×``height`` with almost no pixel data (a lying header)."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    idat = zlib.compress(b"\0" * 64)
    return b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", idat) + _chunk(b"IEND", b"")


def jpeg_claiming(width: int, height: int) -> bytes:
    """A real 32×32 JPEG whose SOF0 is patched to claim ``width``×``height``."""
    import cv2
    import numpy as np

    data = bytearray(cv2.imencode(".jpg", np.zeros((32, 32, 3), np.uint8))[1].tobytes())
    i = data.index(b"\xff\xc0")
    data[i + 5 : i + 9] = struct.pack(">HH", height, width)
    return bytes(data)
