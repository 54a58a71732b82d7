"""The HMI's read-only view of the cycle records: the index, each cycle's log, dirt maps, the audit.

Nothing here writes to the daemon's files: the index is opened read-only (SQLite ``mode=ro``),
logs are only read, and every file served must resolve to a path inside ``recording.dir``
(whatever the index says), so nothing outside ``logs/`` is ever served.
"""

from __future__ import annotations

import base64
import datetime as _dt
import logging
import re
import sqlite3
import tempfile
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from cellctl.bus import keys, topics
from cellctl.config import CellConfig
from cellctl.errors import CellError, RecordingError
from cellctl.recording.index import CycleRow
from cellctl.seen import VERDICTS as SEEN_VERDICTS

__all__ = ["CYCLE_ID", "CycleFilter", "CycleRecords", "NotFound"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

CYCLE_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")
"""What a cycle id may look like in a URL (the supervisor's ids are ``<time>-<ms>-<n>``)."""

OUTCOMES = ("completed", "replan_required", "aborted", "failed", "interrupted", "running")
VERDICTS = (*SEEN_VERDICTS, "none")
"""The history filter's verdicts: a bin's (cellctl.seen), or none (the cycle gave no verdict)."""


class NotFound(CellError):
    """The cycle (or one of its parts) does not exist; the message says which."""


@dataclass(frozen=True)
class CycleFilter:
    outcome: str | None = None
    verdict: str | None = None
    bin_type: str | None = None
    since: str | None = None  # ISO date or time, inclusive
    until: str | None = None  # ISO date or time, inclusive (a date means that whole day)
    limit: int = 50
    before_seq: int | None = None  # paging: rows older than this seq


def _iso(value: str, name: str, end: bool) -> str:
    try:
        if re.fullmatch(r"\d{4}-\d{2}-\d{2}", value):
            d = _dt.date.fromisoformat(value)
            t = _dt.datetime.combine(d, _dt.time.max if end else _dt.time.min, tzinfo=_dt.UTC)
        else:
            t = _dt.datetime.fromisoformat(value)
            if t.tzinfo is None:
                t = t.replace(tzinfo=_dt.UTC)
    except ValueError:
        raise ValueError(f"{name}={value!r} is not a date; expected YYYY-MM-DD or an ISO-8601 time") from None
    return t.astimezone(_dt.UTC).isoformat(timespec="milliseconds")


def _scored(result: dict[str, Any] | None) -> list[dict[str, Any]]:
    """The CycleResult's viewpoints that were captured (in the order of their scanning images)."""
    return [v for v in (result or {}).get("viewpoints", []) if v.get("error") is None]


class CycleRecords:
    """Cycle rows, results, images, dirt maps and audit of one cell's ``recording`` folders."""

    def __init__(self, cfg: CellConfig) -> None:
        self.cfg = cfg
        self.index_path = cfg.path(cfg.recording.index)
        self.logs_root = cfg.path(cfg.recording.dir).resolve()
        self._lock = threading.Lock()
        self._cache: dict[tuple[str, int], dict[str, Any]] = {}
        self._pngs: dict[str, bytes] = {}
        self._audit: tuple[float, tuple[int, float], dict[str, Any]] | None = None
        self._catalog: Any = None
        self._recent: dict[tuple[str, int], Any] = {}
        self._checked: dict[tuple[str, tuple], str] = {}

    # --- the index ---------------------------------------------------------------------------

    def _query(self, sql: str, args: tuple = ()) -> list[CycleRow]:
        if not self.index_path.is_file():
            return []  # no cycle has run yet
        try:
            db = sqlite3.connect(f"{self.index_path.resolve().as_uri()}?mode=ro", uri=True, timeout=2.0)
            try:
                return [CycleRow(*r) for r in db.execute(f"SELECT * FROM cycles {sql}", args)]
            finally:
                db.close()
        except sqlite3.Error as err:
            raise RecordingError(f"cannot read cycle index {str(self.index_path)!r}: {err}") from err

    def cycles(self, f: CycleFilter) -> list[dict[str, Any]]:
        """Rows matching ``f``, newest first.

        Raises:
            ValueError: a filter value is not one of the allowed ones (the message lists them).
        """
        where, args = [], []
        if f.outcome:
            if f.outcome not in OUTCOMES:
                raise ValueError(f"outcome={f.outcome!r} is unknown; expected one of {list(OUTCOMES)}")
            where.append("outcome IS NULL" if f.outcome == "running" else "outcome = ?")
            args += [] if f.outcome == "running" else [f.outcome]
        if f.verdict:
            if f.verdict not in VERDICTS:
                raise ValueError(f"verdict={f.verdict!r} is unknown; expected one of {list(VERDICTS)}")
            where.append("verdict IS NULL" if f.verdict == "none" else "verdict = ?")
            args += [] if f.verdict == "none" else [f.verdict]
        if f.bin_type:
            where.append("bin_type = ?")
            args.append(f.bin_type)
        if f.since:
            where.append("started >= ?")
            args.append(_iso(f.since, "since", end=False))
        if f.until:
            where.append("started <= ?")
            args.append(_iso(f.until, "until", end=True))
        if f.before_seq is not None:
            where.append("seq < ?")
            args.append(f.before_seq)
        sql = ("WHERE " + " AND ".join(where) if where else "") + " ORDER BY seq DESC LIMIT ?"
        rows = self._query(sql, (*args, f.limit))
        return [self._row_dict(r) for r in rows]

    def row(self, cycle_id: str) -> CycleRow:
        """Raises NotFound (also for an id that cannot be one)."""
        if not CYCLE_ID.fullmatch(cycle_id):
            raise NotFound(f"cycle id {cycle_id[:80]!r} is not a cycle id; expected letters, digits, '_', '.', '-'")
        rows = self._query("WHERE cycle_id = ?", (cycle_id,))
        if not rows:
            raise NotFound(f"cycle {cycle_id!r} is not in the cycle index")  # no server path in a 404
        return rows[0]

    def running_row(self) -> CycleRow | None:
        rows = self._query("ORDER BY seq DESC LIMIT 1")
        return rows[0] if rows else None

    @staticmethod
    def _row_dict(r: CycleRow) -> dict[str, Any]:
        d = asdict(r)
        d["log_path"] = d["recovered_path"] = None  # where files lie on the host is not the client's business
        d["duration_s"] = None
        if r.finished:
            try:
                a, b = _dt.datetime.fromisoformat(r.started), _dt.datetime.fromisoformat(r.finished)
                d["duration_s"] = round((b - a).total_seconds(), 3)
            except ValueError:
                pass
        return d

    # --- logs --------------------------------------------------------------------------------

    def _resolve(self, path: str) -> Path:
        p = Path(path)
        return (p if p.is_absolute() else self.cfg.path(p)).resolve()

    def log_file(self, cycle_id: str) -> Path:
        """The cycle's MCAP, only if it lies inside ``recording.dir``.

        Raises:
            NotFound: unknown cycle, missing file, or a path outside the logs folder (an index
                row pointing elsewhere is treated as if it had no log: nothing outside is served).
        """
        row = self.row(cycle_id)
        p = self._resolve(row.readable_log)  # an interrupted cycle's recovered copy: indexed readers need its footer
        if not p.is_relative_to(self.logs_root) or p.suffix != ".mcap":
            log.warning("cycle %s: log path %s is outside %s; not served", cycle_id, p, self.logs_root)
            raise NotFound(f"cycle {cycle_id!r} has no log inside the logs folder")
        if not p.is_file():
            raise NotFound(f"the log of cycle {cycle_id!r} is missing")
        return p

    def detail(self, cycle_id: str) -> dict[str, Any]:
        """The index row, the CycleResult and the per-view image list of one cycle (cached per file size)."""
        row = self.row(cycle_id)
        try:
            path = self.log_file(cycle_id)
        except NotFound:
            return {"row": self._row_dict(row), "result": None, "images": [], "log": False}
        key = (cycle_id, path.stat().st_size)
        with self._lock:
            hit = self._cache.get(key)
        if hit is not None and row.outcome is not None:
            return {**hit, "row": self._row_dict(row)}
        rec = self._read(path)
        result = None
        images: list[dict[str, Any]] = []
        c = self.cfg.cell_id
        pending_image: int | None = None
        n_image = n_heat = 0
        for m in rec.messages:
            if m.topic == topics.CAMERA_IMAGE:
                pending_image = n_image
                n_image += 1
            elif m.topic == topics.CAMERA_POSE and pending_image is not None:
                images.append({"image": pending_image})  # a scanning capture (identification has no pose)
                pending_image = None
            elif m.topic == topics.HEATMAP:
                n_heat += 1
            elif m.topic == keys.result(c):
                result = m.json()
        # classifying records one heat map (topics.HEATMAP) per view with a heat_grid, in viewpoint order;
        # reporting drops the maps themselves from the CycleResult once they are fused per face
        heat_of = [v for v in _scored(result) if v.get("heat_grid")]
        heat_n = {id(v): k for k, v in enumerate(heat_of[:n_heat])}
        for img, v in zip(images, _scored(result), strict=False):
            img.update({"index": v.get("index"), "label": v.get("label"), "p_dirty": v.get("p_dirty"),
                        "uncertain": v.get("uncertain", False), "heatmap": heat_n.get(id(v))})  # fmt: skip
        out = {"row": self._row_dict(row), "result": result, "images": images, "log": True,
               "truncated": rec.truncated}  # fmt: skip
        with self._lock:
            if len(self._cache) > 64:
                self._cache.clear()
            self._cache[key] = out
        return out

    def _read(self, path: Path) -> Any:
        """``read_cycle`` of ``path``, the last two kept (a detail page asks for each of its images)."""
        from cellctl.recording.replay import read_cycle

        key = (str(path), path.stat().st_size)
        with self._lock:
            hit = self._recent.get(key)
        if hit is not None:
            return hit
        rec = read_cycle(path)
        with self._lock:
            self._recent[key] = rec
            while len(self._recent) > 2:
                self._recent.pop(next(iter(self._recent)))
        return rec

    def image(self, cycle_id: str, n: int) -> tuple[bytes, str]:
        """The ``n``-th image of the cycle's log (0-based, identification images included)."""
        rec = self._read(self.log_file(cycle_id))
        imgs = rec.on(topics.CAMERA_IMAGE)
        if not 0 <= n < len(imgs):
            raise NotFound(f"cycle {cycle_id!r} has {len(imgs)} images; image {n} does not exist")
        obj = imgs[n].json()
        return base64.b64decode(obj["data"]), obj.get("format", "png")

    def heat_image(self, cycle_id: str, n: int) -> bytes:
        """The heat map of the view whose image is the ``n``-th of the log, over that image (PNG).

        Raises:
            NotFound: no such image, or its view has no heat map in the log.
        """
        from cellctl.hmi.live import blend_heat

        d = self.detail(cycle_id)
        k = next((img.get("heatmap") for img in d["images"] if img["image"] == n), None)
        if k is None:
            raise NotFound(f"image {n} of cycle {cycle_id!r} is not a classified view with a heat map")
        heat = self._read(self.log_file(cycle_id)).on(topics.HEATMAP)[k]
        image, data = self.image(cycle_id, n)[0], base64.b64decode(heat.json()["data"])
        return blend_heat(image, data, self.cfg.camera.max_image_pixels)

    def dirt_map_png(self, cycle_id: str) -> bytes:
        """The cycle's dirt map drawn on its bin mesh, as PNG bytes (rendered once, the last 32 kept
        in memory: an HMI killed by a signal leaves no cache folder behind)."""
        with self._lock:
            hit = self._pngs.get(cycle_id)
        if hit is not None:
            return hit
        d = self.detail(cycle_id)
        res = d["result"] or {}
        dm, bin_type = res.get("dirt_map"), (res.get("bin") or {}).get("type")
        if not dm or not bin_type:
            raise NotFound(f"cycle {cycle_id!r} has no dirt map (outcome {res.get('outcome') or d['row']['outcome']})")
        from cellctl.recording.dirt_map import draw_dirt_map

        if self._catalog is None:
            from cellctl.geometry.catalog import load_catalog

            self._catalog = load_catalog(self.cfg.path(self.cfg.catalog))
        mesh = self._catalog.load_mesh(bin_type)
        with tempfile.TemporaryDirectory(prefix="cellctl-hmi-") as tmp:
            out = draw_dirt_map(mesh, dm, Path(tmp) / "dirt_map.png", title=f"{cycle_id} {res.get('verdict') or ''}")
            png = out.read_bytes()
        with self._lock:
            self._pngs[cycle_id] = png
            while len(self._pngs) > 32:
                self._pngs.pop(next(iter(self._pngs)))
        return png

    # --- audit -------------------------------------------------------------------------------

    def audit(self, max_age_s: float = 30.0) -> dict[str, Any]:
        """``verify_audit`` of the index and logs with its head; re-run when the index changed or aged.

        Raises:
            RecordingError: the index is missing or unreadable.
        """
        from cellctl.recording.audit import verify_audit

        st = self.index_path.stat() if self.index_path.is_file() else None
        wal = self.index_path.with_name(self.index_path.name + "-wal")
        stamp = (st.st_size if st else 0, max(st.st_mtime if st else 0, wal.stat().st_mtime if wal.exists() else 0))
        now = time.monotonic()
        with self._lock:
            cached = self._audit
        if cached is not None and cached[1] == stamp and now - cached[0] < max_age_s:
            return cached[2]
        report = verify_audit(self.index_path, self.logs_root).as_dict()
        report["checked_at"] = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        report["index"] = self.index_path.name
        report["logs_root"] = "logs"
        for f in report["findings"]:
            f["path"] = Path(f["path"]).name if f.get("path") else None
        with self._lock:
            self._audit = (now, stamp, report)
        return report

    def audit_status(self, cycle_id: str) -> dict[str, Any]:
        """This record's links of the audit, without hashing every log (``GET /api/audit`` does that):
        its row hash, its link to the row before it, its log's sha256.

        Returns:
            ``{"status": "ok" | "tamper" | "running", "findings": [str], "head": {"seq", "row_hash"}}``
        """
        from cellctl.recording.audit import checked_log
        from cellctl.recording.index import GENESIS, row_hash

        row = self.row(cycle_id)
        heads = self._query("WHERE row_hash IS NOT NULL ORDER BY seq DESC LIMIT 1")
        head = {"seq": heads[0].seq, "row_hash": heads[0].row_hash} if heads else None
        if row.outcome is None:
            return {"status": "running", "findings": [], "head": head}
        findings = []
        if row.row_hash is None:
            findings.append("the closed row has no hash")
        else:
            before = self._query("WHERE row_hash IS NOT NULL AND seq < ? ORDER BY seq DESC LIMIT 1", (row.seq,))
            want = before[0].row_hash if before else GENESIS
            if row.prev_hash != want:
                findings.append(f"prev_hash {row.prev_hash} is not the hash of the row before ({want}): rows deleted?")
            elif row_hash(row.prev_hash, row) != row.row_hash:
                findings.append("the row's fields do not hash to its row_hash: the record was edited")
        files = [self._resolve(q) for q in (row.log_path, row.recovered_path) if q]
        if not all(f.is_relative_to(self.logs_root) for f in files):
            findings.append("its log path lies outside the logs folder")
        else:
            key = (cycle_id, tuple((f.stat().st_size, f.stat().st_mtime_ns) if f.is_file() else None for f in files))
            with self._lock:
                problem = self._checked.get(key)
            if problem is None:
                try:
                    checked_log(row)  # the audit's own check of the log (and of a recovered copy)
                    problem = ""
                except RecordingError as err:
                    problem = str(err)
                with self._lock:
                    self._checked[key] = problem
            if problem:
                findings.append(problem)
        return {"status": "tamper" if findings else "ok", "findings": findings, "head": head}

    def close(self) -> None:
        with self._lock:
            self._pngs.clear()
