"""One MCAP file per cycle: every command, ack, status, worker request/reply and event.

Crash safety: the file is written without chunks and flushed after every message, so a
supervisor killed mid-cycle leaves every message written so far readable with a streaming
reader (measured: chunked files lose the open chunk; see docs/decisions.md).
"""

from __future__ import annotations

import base64
import json
import threading
import time
from pathlib import Path
from typing import IO, Any

from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from cellctl import __version__
from cellctl.bus import topics
from cellctl.errors import RecordingError
from cellctl.messages import MESSAGE_TYPES, WireMessage
from cellctl.recording import foxglove

__all__ = ["CycleLog"]


class CycleLog:
    """Writer of one cycle's MCAP; thread-safe (steps and the dispatcher both write).

    Args:
        path: the ``.mcap`` file to create (parent folders are made).
        cycle_id: recorded as metadata.
    """

    def __init__(self, path: Path, cycle_id: str, metadata: dict[str, str] | None = None) -> None:
        self.path = Path(path)
        self.cycle_id = cycle_id
        self._lock = threading.Lock()
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str], int] = {}
        self._seq = 0
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file: IO[bytes] | None = open(self.path, "wb")  # closed in close()
        except OSError as err:
            raise RecordingError(f"cannot create cycle log {str(self.path)!r}: {err}") from err
        self._writer = Writer(self._file, use_chunking=False, compression=CompressionType.NONE)
        self._writer.start(profile="", library=f"cellctl/{__version__}")
        self._writer.add_metadata("cycle", {"cycle_id": cycle_id, **(metadata or {})})
        self._file.flush()

    @property
    def closed(self) -> bool:
        return self._file is None

    def _schema_id(self, name: str) -> int:
        sid = self._schemas.get(name)
        if sid is None:
            if name in foxglove.SCHEMAS:
                data = foxglove.schema_bytes(name)
            elif name in MESSAGE_TYPES:
                data = json.dumps(MESSAGE_TYPES[name].model_json_schema()).encode()
            else:
                data = b'{"type": "object"}'
            sid = self._writer.register_schema(name=name, encoding=SchemaEncoding.JSONSchema, data=data)
            self._schemas[name] = sid
        return sid

    def _channel_id(self, topic: str, schema: str) -> int:
        cid = self._channels.get((topic, schema))
        if cid is None:
            cid = self._writer.register_channel(
                topic=topic, message_encoding=MessageEncoding.JSON, schema_id=self._schema_id(schema)
            )
            self._channels[(topic, schema)] = cid
        return cid

    def write_json(self, topic: str, schema: str, obj: dict[str, Any] | bytes, t_ns: int | None = None) -> None:
        """Append one JSON message on ``topic`` under schema ``schema``."""
        data = obj if isinstance(obj, bytes) else json.dumps(obj, separators=(",", ":")).encode()
        t = time.time_ns() if t_ns is None else t_ns
        with self._lock:
            if self._file is None:
                return  # late replies of an aborted cycle arrive after the log closed
            cid = self._channel_id(topic, schema)
            self._writer.add_message(channel_id=cid, log_time=t, publish_time=t, data=data, sequence=self._seq)
            self._seq += 1
            self._file.flush()

    def write_message(self, topic: str, msg: WireMessage, t_ns: int | None = None) -> None:
        """Append a wire message on the bus key it travelled on."""
        self.write_json(topic, msg.type, msg.model_dump_json().encode(), t_ns)

    def event(self, level: int, text: str, t_ns: int | None = None) -> None:
        self.write_json(topics.EVENTS, "foxglove.Log", foxglove.log(level, text, "supervisor", t_ns), t_ns)

    def image(self, topic: str, data: bytes, fmt: str, frame_id: str = "camera", t_ns: int | None = None) -> None:
        """Append a foxglove.CompressedImage.

        Hot path (one per viewpoint): the JSON is assembled around the base64 text instead of
        passing a multi-MB string through ``json.dumps`` (base64 needs no escaping).
        """
        t = time.time_ns() if t_ns is None else t_ns
        head = json.dumps({"timestamp": foxglove.stamp(t), "frame_id": frame_id, "format": fmt})
        body = head[:-1].encode() + b',"data":"' + base64.b64encode(data) + b'"}'
        self.write_json(topic, "foxglove.CompressedImage", body, t)

    def close(self, metadata: dict[str, str] | None = None) -> None:
        """Write the summary and close; safe to call twice."""
        with self._lock:
            if self._file is None:
                return
            try:
                if metadata:
                    self._writer.add_metadata("result", metadata)
                self._writer.finish()
            finally:
                self._file.close()
                self._file = None
