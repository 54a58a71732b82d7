"""Hostile images built in memory: a real decompression-bomb PNG and truncations of good files."""

from __future__ import annotations

import struct
import zlib

__all__ = ["png_bomb"]


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
