"""The reviewed-view bank: views an operator confirmed clean or dirty, with their provenance.

Layout under ``review.dir`` (default ``<recording.dir>/review``)::

    manifest.json                         format, bound, every entry kept, eviction counts
    <surface>/clean/<cycle>-<image>.<ext>  confirmed-clean views: re-enrolled by `cellctl detector update`
    <surface>/dirty/<cycle>-<image>.<ext>  confirmed-dirty views: labelled training examples

Each manifest entry holds the provenance: cycle, image number, viewpoint, user, role, time, reason,
the image's sha256 and the ledger entry (``decision_hash``) that put it there.

**Bound and eviction**: at most ``review.max_per_label`` views per surface and label. Adding one
beyond it evicts the *oldest decision* of that surface and label (first in, first out): the bank
follows the plant as it drifts (new bins, a changed wash), and a surface's clean set never grows
without end. An evicted view's file is deleted and its count kept in ``evicted``; what it was, who
decided it and why stays in the review ledger, which is never pruned.

The manifest is rewritten atomically (temporary file, ``os.replace``) under the same lock file
discipline as the ledger.
"""

from __future__ import annotations

import fcntl
import json
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from cellctl.errors import RecordingError
from cellctl.hashing import bytes_sha256
from cellctl.surface import check_surface

if TYPE_CHECKING:
    from cellctl.config import CellConfig

__all__ = ["BANK_FORMAT", "Label", "ReviewBank", "bank_dir", "open_bank"]

BANK_FORMAT = "cellctl-review-bank/1"
Label = Literal["clean", "dirty"]
_EXT = {"png": "png", "jpeg": "jpg", "jpg": "jpg"}


class ReviewBank:
    """The bounded store of reviewed views of one cell (module doc).

    Args:
        root: the bank folder (``review.dir``).
        max_per_label: views kept per surface and label.
    """

    def __init__(self, root: Path, max_per_label: int) -> None:
        self.root = Path(root)
        self.max_per_label = max_per_label
        self._lock = threading.Lock()

    @property
    def manifest_path(self) -> Path:
        return self.root / "manifest.json"

    @contextmanager
    def _locked(self) -> Iterator[None]:
        with self._lock:
            self.root.mkdir(parents=True, exist_ok=True)
            with open(self.root / ".lock", "a") as lk:
                fcntl.flock(lk, fcntl.LOCK_EX)
                try:
                    yield
                finally:
                    fcntl.flock(lk, fcntl.LOCK_UN)

    def manifest(self) -> dict[str, Any]:
        """The manifest (an empty one when the bank holds nothing yet).

        Raises:
            RecordingError: the manifest exists but is not ours.
        """
        if not self.manifest_path.is_file():
            return {"format": BANK_FORMAT, "max_per_label": self.max_per_label, "entries": [], "evicted": {}}
        try:
            m = json.loads(self.manifest_path.read_text())
        except (OSError, ValueError) as err:
            raise RecordingError(f"review bank manifest {str(self.manifest_path)!r} is unreadable: {err}") from err
        if not isinstance(m, dict) or m.get("format") != BANK_FORMAT:
            got = m.get("format") if isinstance(m, dict) else type(m).__name__
            raise RecordingError(f"review bank manifest format {got!r}; expected {BANK_FORMAT!r}")
        return m

    def add(self, surface: str, label: Label, image: bytes, fmt: str, provenance: dict[str, Any]) -> dict[str, Any]:
        """Store one reviewed view; returns its manifest entry (with ``evicted``: files removed for it).

        Args:
            provenance: at least ``cycle_id`` and ``image`` (its number in the cycle's log); also
                viewpoint, user, role, time, reason, decision_hash.

        Raises:
            RecordingError: unknown surface/label/format, or the bank cannot be written.
        """
        check_surface(surface, RecordingError)
        if label not in ("clean", "dirty"):
            raise RecordingError(f"bank label {label!r} is unknown; expected 'clean' or 'dirty'")
        ext = _EXT.get(fmt.lower())
        if ext is None:
            raise RecordingError(f"image format {fmt!r} cannot be banked; expected one of {sorted(_EXT)}")
        rel = Path(surface) / label / f"{provenance['cycle_id']}-{int(provenance['image'])}.{ext}"
        with self._locked():
            m = self.manifest()
            m["max_per_label"] = self.max_per_label
            entry = {"surface": surface, "label": label, "file": rel.as_posix(), "sha256": bytes_sha256(image),
                     "bytes": len(image), **provenance}  # fmt: skip
            try:
                (self.root / rel).parent.mkdir(parents=True, exist_ok=True)
                tmp = self.root / rel.with_name(rel.name + ".tmp")
                tmp.write_bytes(image)
                os.replace(tmp, self.root / rel)
            except OSError as err:
                raise RecordingError(f"review bank {str(self.root)!r} cannot be written: {err.strerror}") from err
            kept = [e for e in m["entries"] if e["file"] != entry["file"]]
            kept.append(entry)
            same = [e for e in kept if e["surface"] == surface and e["label"] == label]
            gone = same[: max(0, len(same) - self.max_per_label)]  # oldest first: entries are in decision order
            for e in gone:
                (self.root / e["file"]).unlink(missing_ok=True)
                kept.remove(e)
            ev = m.setdefault("evicted", {}).setdefault(surface, {})
            ev[label] = int(ev.get(label, 0)) + len(gone)
            m["entries"] = kept
            self._write(m)
        return {**entry, "evicted": [e["file"] for e in gone]}

    def _write(self, m: dict[str, Any]) -> None:
        tmp = self.manifest_path.with_name("manifest.json.tmp")
        try:
            tmp.write_text(json.dumps(m, indent=1) + "\n")
            os.replace(tmp, self.manifest_path)
        except OSError as err:
            raise RecordingError(f"review bank manifest cannot be written: {err.strerror}") from err

    def entries(self, surface: str | None = None, label: Label | None = None) -> list[dict[str, Any]]:
        return [e for e in self.manifest()["entries"] if (surface is None or e["surface"] == surface)
                and (label is None or e["label"] == label)]  # fmt: skip

    def files(self, surface: str, label: Label) -> list[Path]:
        """The stored files of ``surface``/``label`` that still match their recorded sha256.

        Raises:
            RecordingError: a file is missing or differs from its manifest hash (the bank was edited).
        """
        out = []
        for e in self.entries(surface, label):
            p = self.root / e["file"]
            try:
                data = p.read_bytes()
            except OSError:
                raise RecordingError(f"review bank file {e['file']!r} is missing (manifest entry of cycle "
                                     f"{e.get('cycle_id')})") from None  # fmt: skip
            if bytes_sha256(data) != e["sha256"]:
                raise RecordingError(f"review bank file {e['file']!r} has changed since it was reviewed")
            out.append(p)
        return out

    def counts(self) -> dict[str, dict[str, int]]:
        """Views kept per surface and label."""
        out: dict[str, dict[str, int]] = {}
        for e in self.manifest()["entries"]:
            d = out.setdefault(e["surface"], {"clean": 0, "dirty": 0})
            d[e["label"]] += 1
        return out


def bank_dir(cfg: CellConfig) -> Path:
    """The bank folder of a cell: ``review.dir``, else ``<recording.dir>/review``."""
    d = cfg.review.dir
    return cfg.path(d) if d is not None else cfg.path(cfg.recording.dir) / "review"


def open_bank(cfg: CellConfig) -> ReviewBank:
    """The cell's review bank with its configured bound."""
    return ReviewBank(bank_dir(cfg), cfg.review.max_per_label)
