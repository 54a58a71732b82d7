"""The running cycle as the live page shows it, read from the cycle's MCAP while it is written.

The supervisor writes each cycle log unchunked and flushed after every message
(cellctl.recording.cycle_log), so the file is a plain sequence of records that can be tailed:
:class:`McapTail` parses only the bytes added since the last poll and stops at a record that
is not complete yet. The worker requests and replies travel as Zenoh queries between the
supervisor and the workers, which no other client can observe; the log is where they are.
"""

from __future__ import annotations

import base64
import json
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cellctl.bus import keys, topics
from cellctl.errors import ClassifierError
from cellctl.images import MAX_IMAGE_PIXELS
from cellctl.recording.replay import MCAP_MAGIC, RecordedMessage

__all__ = ["LiveCycle", "McapTail", "blend_heat"]

_OP_CHANNEL, _OP_MESSAGE, _OP_SCHEMA = 0x04, 0x05, 0x03
_MAX_READ = 64 << 20


def _string(buf: bytes, at: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, at)
    return buf[at + 4 : at + 4 + n].decode("utf-8", "replace"), at + 4 + n


def _decode_bgr(data: bytes, max_pixels: int) -> Any:
    """OpenCV's BGR image, or None for a damaged one or one over the cell's pixel budget ``max_pixels`` (read
    from its header first: these bytes come off the bus or a log, and a decompression bomb must not reach the
    decoder)."""
    import cv2
    import numpy as np

    from cellctl.errors import CellError
    from cellctl.images import check_budget

    try:
        check_budget(data, max_pixels=max_pixels)
    except CellError:
        return None
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)


def blend_heat(image: bytes | None, heat: bytes, max_pixels: int = MAX_IMAGE_PIXELS) -> bytes:
    """A heat-map PNG (:func:`cellctl.classify.heatmap.heat_png`) blended over its view's image.

    The detector's grid covers the whole (squashed) image, so stretched to the image's size each
    patch lies over the pixels it scored. Without a readable image (or one over the cell's budget
    ``max_pixels``, ``camera.max_image_pixels``), the heat map alone.
    """
    import cv2

    colour = _decode_bgr(heat, max_pixels)
    base = _decode_bgr(image, max_pixels) if image else None
    if base is None or colour is None:
        return heat
    h, w = base.shape[:2]
    colour = cv2.resize(colour, (w, h), interpolation=cv2.INTER_NEAREST)
    ok, buf = cv2.imencode(".png", cv2.addWeighted(base, 0.45, colour, 0.55, 0.0))
    return buf.tobytes() if ok else heat


def _image_bytes(raw: bytes) -> tuple[bytes, str] | None:
    """A logged CompressedImage message's JSON → its bytes and format."""
    try:
        obj = json.loads(raw)
        return base64.b64decode(obj["data"]), obj.get("format", "png")
    except (ValueError, KeyError, TypeError):
        return None


class McapTail:
    """Incremental reader of an unchunked MCAP that is still being written.

    Args:
        path: the cycle log.
        on_message: called with each complete message, in file order.
    """

    def __init__(self, path: Path, on_message: Callable[[RecordedMessage], None]) -> None:
        self.path = Path(path)
        self.offset = 0
        self._on_message = on_message
        self._schemas: dict[int, str] = {}
        self._channels: dict[int, tuple[str, int]] = {}

    def poll(self) -> int:
        """Read what was appended since the last call; returns the number of new messages."""
        try:
            with self.path.open("rb") as f:
                f.seek(self.offset)
                buf = f.read(_MAX_READ)
        except OSError:
            return 0
        at, n = 0, 0
        if self.offset == 0:
            if len(buf) < len(MCAP_MAGIC):
                return 0
            if buf[: len(MCAP_MAGIC)] != MCAP_MAGIC:
                self.offset = -1  # not MCAP: never read it again
                return 0
            at = len(MCAP_MAGIC)
        if self.offset < 0:
            return 0
        while len(buf) - at >= 9:
            op, length = struct.unpack_from("<BQ", buf, at)
            end = at + 9 + length
            if end > len(buf):
                break  # the writer has not finished this record yet
            body = buf[at + 9 : end]
            if op == _OP_SCHEMA:
                (sid,) = struct.unpack_from("<H", body, 0)
                self._schemas[sid] = _string(body, 2)[0]
            elif op == _OP_CHANNEL:
                cid, sid = struct.unpack_from("<HH", body, 0)
                self._channels[cid] = (_string(body, 4)[0], sid)
            elif op == _OP_MESSAGE:
                cid, _seq, log_time, _pub = struct.unpack_from("<HIQQ", body, 0)
                topic, sid = self._channels.get(cid, ("?", 0))
                self._on_message(RecordedMessage(topic, self._schemas.get(sid, ""), log_time, bytes(body[22:])))
                n += 1
            at = end
        self.offset += at
        return n


@dataclass
class LiveCycle:
    """What the live page shows of one cycle, folded from its log messages."""

    cell: str
    cycle_id: str
    step: str | None = None
    state: str | None = None
    bin_type: str | None = None
    n_viewpoints: int | None = None
    moves: int = 0
    captured: int = 0
    steps_seen: list[str] = field(default_factory=list)
    verdicts: list[dict[str, Any]] = field(default_factory=list)
    image_seq: int = 0
    result: dict[str, Any] | None = None
    messages: int = 0
    heat: dict[str, Any] | None = None
    _last_image: bytes | None = None
    _unposed: bytes | None = None  # the newest image until a camera pose says it was a scanning capture
    _decoded: tuple[bytes, str] | None = None
    _scans: dict[int, bytes] = field(default_factory=dict)  # the last classified images (raw log JSON) by verdict n
    _heat_raw: tuple[int, str, int] | None = None  # (view n, heatmap, heat_grid) of the newest reply that has one
    _heat_png: tuple[int, bytes] | None = None
    _classify_requests: int = 0
    max_pixels: int = MAX_IMAGE_PIXELS  # the cell's camera.max_image_pixels: the heat overlay decodes under it

    def fold(self, m: RecordedMessage) -> None:
        """Update the view with one log message (called by :class:`McapTail`)."""
        c = self.cell
        self.messages += 1
        t = m.topic
        if t == topics.CAMERA_IMAGE:
            self._last_image = self._unposed = m.data  # decoded lazily: only the newest image is shown
            self.image_seq += 1
            return
        if t == topics.CAMERA_POSE:
            self.captured += 1  # a scanning capture: its image is the one just before (identification has no pose)
            if self._unposed is not None:
                self._scans[self.captured], self._unposed = self._unposed, None
                for n in [n for n in self._scans if n <= self.captured - 8]:
                    del self._scans[n]  # a classification lags a few views behind at most
            return
        if t == topics.request(keys.classifier_classify(c)):
            self._classify_requests += 1
            if self._classify_requests > self.captured and self._unposed is not None:
                # a re-look (classifying): its image has no pose and goes to the classifier at once
                self._scans[self._classify_requests], self._unposed = self._unposed, None
            return
        if t == topics.request(keys.robot_op(c, "move")) and self.n_viewpoints is not None:
            self.moves += 1
            return
        try:
            obj = m.json()
        except ValueError:
            return
        if t == keys.status(c):
            self.step, self.state = obj.get("step"), obj.get("state")
            if self.step and self.step not in self.steps_seen:
                self.steps_seen.append(self.step)
        elif t == topics.reply(keys.worker_op(c, "planner", "lookup")) and obj.get("hit"):
            self.n_viewpoints = len(obj.get("viewpoints") or [])
        elif t == topics.reply(keys.classifier_classify(c)):
            if obj.get("type") == "cellctl/ClassifyReply":
                n = len(self.verdicts) + 1
                if obj.get("heatmap") and obj.get("heat_grid"):
                    # the reply, not the /classifier/heatmap image: that one is logged only once the
                    # scan is over (classifying), the reply as each view's verdict arrives
                    self._heat_raw = (n, obj["heatmap"], int(obj["heat_grid"]))
                    self.heat = {"view": n, "seq": n, "label": obj.get("label"), "p_dirty": obj.get("p_dirty")}
                self.verdicts.append(
                    {
                        "n": len(self.verdicts) + 1,
                        "label": obj.get("label"),
                        "p_dirty": obj.get("p_dirty"),
                        "uncertain": obj.get("uncertain", False),
                    }  # fmt: skip
                )
            else:
                self.verdicts.append({"n": len(self.verdicts) + 1, "label": None, "error": obj.get("reason")})
        elif t == topics.BIN_IDENTIFICATION:
            self.bin_type = obj.get("bin_type") or self.bin_type
        elif t == keys.result(c):
            self.result = obj
            self.bin_type = (obj.get("bin") or {}).get("type") or self.bin_type

    def image(self) -> tuple[bytes, str] | None:
        """The newest image's bytes and format, decoded on first request (not on every poll: a
        base64 decode of each frame would hold the GIL the status requests need)."""
        if self._last_image is not None:
            self._decoded = _image_bytes(self._last_image) or self._decoded
            self._last_image = None
        return self._decoded

    def heat_image(self) -> bytes | None:
        """The newest heat map over its own view's image, as PNG (rendered once per heat map)."""
        if self._heat_raw is None:
            return None
        n, heatmap, grid = self._heat_raw
        if self._heat_png is None or self._heat_png[0] != n:
            from cellctl.classify.heatmap import decode_heat, heat_png

            raw = self._scans.get(n)
            img = _image_bytes(raw) if raw is not None else None
            try:
                heat = heat_png(decode_heat(heatmap, grid))
            except ClassifierError:
                return None  # a malformed map in the log: the page shows none rather than failing
            self._heat_png = (n, blend_heat(img[0] if img else None, heat, self.max_pixels))
        return self._heat_png[1]

    def as_dict(self) -> dict[str, Any]:
        res = self.result or {}
        return {
            "cycle_id": self.cycle_id,
            "state": self.state,
            "step": self.step,
            "bin_type": self.bin_type,
            "viewpoint": min(self.moves, self.n_viewpoints) if self.n_viewpoints else None,
            "n_viewpoints": self.n_viewpoints,
            "captured": self.captured,
            "steps_seen": self.steps_seen,
            "verdicts": self.verdicts,
            "image_seq": self.image_seq or None,
            "heat_map": self.heat,
            "outcome": res.get("outcome"),
            "verdict": res.get("verdict"),
            "coverage": res.get("coverage"),
            "coverage_by_surface": res.get("coverage_by_surface"),
            "min_seen_fraction": res.get("min_seen_fraction"),
            "reason": res.get("reason"),
        }
