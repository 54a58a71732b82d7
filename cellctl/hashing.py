"""SHA-256 of files and byte strings: the one helper behind every recorded digest.

Mesh hashes in ``config/bins.yaml``, cycle-log hashes in the index and audit chain, model
and backbone hashes in classifier model cards are all hex SHA-256 of the file's bytes, read
in 1 MiB blocks so a large log or model is never held in memory at once.

Leaf module: standard library only (the daemon imports it).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

__all__ = ["bytes_sha256", "file_sha256", "file_sha256_or_none"]

_BLOCK = 1 << 20


def bytes_sha256(data: bytes) -> str:
    """Hex SHA-256 of ``data`` (the digest of a file whose bytes are already in memory)."""
    return hashlib.sha256(data).hexdigest()


def file_sha256(path: Path | str) -> str:
    """Hex SHA-256 of the bytes of the file at ``path``.

    Raises:
        OSError: the file cannot be opened or read.
    """
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(_BLOCK), b""):
            h.update(block)
    return h.hexdigest()


def file_sha256_or_none(path: Path | str) -> str | None:
    """:func:`file_sha256`, or None when the file is missing or unreadable.

    For evidence records (index rows, audits) where a missing file is itself the finding.
    """
    try:
        return file_sha256(path)
    except OSError:
        return None
