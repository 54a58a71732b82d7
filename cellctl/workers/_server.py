"""The runtime every worker process shares: ops served as Zenoh queryables, a liveliness
token, clean shutdown.

Zenoh callbacks never run worker code: each op's queryable feeds a FIFO queue drained by
its own thread, so a long ``move`` does not block ``state`` or ``stop``.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from cellctl.bus import keys
from cellctl.bus.codec import MAX_PAYLOAD_BYTES, decode, decode_as, encode
from cellctl.errors import CellError, ProtocolError
from cellctl.images import MAX_IMAGE_BYTES
from cellctl.messages import ErrorReply, WireMessage

__all__ = ["Handler", "WorkerServer"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

Handler = Callable[[Any, bytes | None], "WireMessage | tuple[WireMessage, bytes]"]
"""``handler(request, payload) -> reply`` or ``(reply, image_bytes)``; raise CellError to refuse."""


@dataclass
class _Op:
    key: str
    request_type: type[WireMessage] | tuple[type[WireMessage], ...]
    handler: Handler
    queryable: Any
    thread: threading.Thread


def _decode_any(types: type[WireMessage] | tuple[type[WireMessage], ...], data: bytes) -> WireMessage:
    if not isinstance(types, tuple):
        return decode_as(types, data, MAX_PAYLOAD_BYTES)
    msg = decode(data, MAX_PAYLOAD_BYTES)
    if not isinstance(msg, types):
        names = [t.model_fields["type"].default for t in types]
        raise ProtocolError(f"expected one of {names}, got {msg.type}")
    return msg


class WorkerServer:
    """Serve a worker role's ops on the bus.

    Args:
        session: an open Zenoh session (client mode).
        cell_id: the cell this worker belongs to.
        role: one of :data:`cellctl.bus.keys.ROLES`.
        instance: instance name for roles that run several workers (planners).
    """

    def __init__(self, session: zenoh.Session, cell_id: str, role: str, instance: str | None = None) -> None:
        self.session = session
        self.cell_id = cell_id
        self.role = role
        self.instance = instance
        self._ops: dict[str, _Op] = {}
        self._token: Any = None
        self._closed = threading.Event()

    def serve(
        self,
        op: str,
        request_type: type[WireMessage] | tuple[type[WireMessage], ...],
        handler: Handler,
        *,
        key: str | None = None,
    ) -> None:
        """Serve ``op`` (key ``cell/<id>/<role>/<op>`` unless ``key`` is given).

        ``request_type`` may be a tuple when one key accepts several messages (planner jobs:
        submit and status query); the handler then dispatches on the decoded type.
        """
        k = key or keys.worker_op(self.cell_id, self.role, op)
        inbox: queue.Queue[Any] = queue.Queue()
        # The callback only enqueues: Zenoh threads never run worker code.
        queryable = self.session.declare_queryable(k, inbox.put, complete=True)
        thread = threading.Thread(target=self._drain, args=(op, inbox), name=f"{self.role}-{op}", daemon=True)
        self._ops[op] = _Op(k, request_type, handler, queryable, thread)
        thread.start()

    def announce(self) -> None:
        """Declare the liveliness token: from now on the supervisor sees this worker alive."""
        if self._token is None:
            self._token = self.session.liveliness().declare_token(keys.alive(self.cell_id, self.role, self.instance))

    def withdraw(self) -> None:
        """Undeclare the token while serving on: the role is unavailable (e.g. a robot safety fault)."""
        if self._token is not None:
            self._token.undeclare()
            self._token = None

    def _drain(self, op: str, inbox: queue.Queue[Any]) -> None:
        while not self._closed.is_set():
            try:
                query = inbox.get(timeout=0.2)
            except queue.Empty:
                continue
            try:
                self._answer(op, query)
            finally:
                query.drop()

    def _answer(self, op: str, query: Any) -> None:
        spec = self._ops[op]
        try:
            payload = query.payload.to_bytes() if query.payload is not None else b""
            attachment = query.attachment.to_bytes() if query.attachment is not None else None
            if attachment is not None:
                if len(payload) > MAX_IMAGE_BYTES:
                    raise CellError(f"image payload of {len(payload)} bytes exceeds {MAX_IMAGE_BYTES}")
                request = _decode_any(spec.request_type, attachment)
                raw: bytes | None = payload
            else:
                request = _decode_any(spec.request_type, payload)
                raw = None
            out = spec.handler(request, raw)
            if isinstance(out, tuple):
                reply, image = out
                query.reply(query.key_expr, image, attachment=encode(reply))
            else:
                query.reply(query.key_expr, encode(out))
        except CellError as err:
            log.warning("%s/%s refused: %s", self.role, op, err)
            query.reply_err(encode(ErrorReply(kind=type(err).__name__, reason=str(err))))
        except Exception as err:  # a bug in a handler must not kill the worker
            log.exception("%s/%s crashed", self.role, op)
            query.reply_err(encode(ErrorReply(kind="InternalError", reason=f"{type(err).__name__}: {err}")))

    def close(self) -> None:
        self._closed.set()
        if self._token is not None:
            self._token.undeclare()
            self._token = None
        for spec in self._ops.values():
            spec.queryable.undeclare()
        for spec in self._ops.values():
            spec.thread.join(timeout=2.0)
        self._ops.clear()

    def __enter__(self) -> WorkerServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
