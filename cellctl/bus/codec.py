"""JSON codec for the versioned wire messages of :mod:`cellctl.messages`."""

from __future__ import annotations

import json
from collections.abc import Iterable
from typing import Any, TypeVar

from pydantic import ValidationError

from cellctl.errors import ProtocolError
from cellctl.messages import MAX_REQUEST_ID_CHARS, MESSAGE_TYPES, WireMessage

__all__ = [
    "MAX_JSON_DEPTH",
    "MAX_PAYLOAD_BYTES",
    "decode",
    "decode_as",
    "encode",
    "json_schemas",
    "peek_request_id",
]

MAX_PAYLOAD_BYTES = 64 * 1024
"""Largest control payload accepted; images travel separately and are not decoded here."""

MAX_JSON_DEPTH = 32
"""Deepest nesting of arrays/objects accepted; every message fits in 6. A deeper payload would
otherwise reach Python's recursion limit in the parser or later, in whoever walks it."""

M = TypeVar("M", bound=WireMessage)


def encode(msg: WireMessage) -> bytes:
    """Serialise a message to compact JSON bytes."""
    return msg.model_dump_json(exclude_none=False).encode()


def _explain(err: ValidationError) -> str:
    parts = []
    for e in err.errors():
        loc = ".".join(str(x) for x in e["loc"]) or "(message)"
        given = e.get("input")
        shown = repr(given) if not isinstance(given, dict) else "{…}"
        if len(shown) > 80:
            shown = shown[:77] + "..."
        parts.append(f"{loc}: {e['msg']} (got {shown})")
    return "; ".join(parts)


def _too_deep(obj: object, limit: int) -> bool:
    """True if ``obj`` nests containers deeper than ``limit`` (iterative: hostile input cannot recurse)."""
    stack = [(obj, 1)]
    while stack:
        o, depth = stack.pop()
        if depth > limit:
            return True
        children: Iterable[object] = o.values() if isinstance(o, dict) else o if isinstance(o, list) else ()
        stack.extend((c, depth + 1) for c in children if isinstance(c, dict | list))
    return False


def _unique_keys(pairs: list[tuple[str, object]]) -> dict[str, object]:
    obj = dict(pairs)
    if len(obj) != len(pairs):
        # Parsers disagree on which duplicate wins; a gateway checking the first while we act on the last is a hole.
        seen: set[str] = set()
        for k, _ in pairs:
            if k in seen:
                raise ProtocolError(f"payload repeats key {k[:60]!r} in one object; expected unique keys")
            seen.add(k)
    return obj


def _parse(raw: bytes) -> object:
    """Strict UTF-8 (RFC 8259: no BOM, no UTF-16/32) JSON of bounded depth, or ProtocolError."""
    shown = raw[:60]
    try:
        obj = json.loads(raw.decode("utf-8"), object_pairs_hook=_unique_keys)
    except UnicodeDecodeError as err:
        raise ProtocolError(
            f"payload is not valid JSON (not UTF-8: {err.reason} at byte {err.start}); got {shown!r}"
        ) from err
    except RecursionError as err:
        raise ProtocolError(f"payload nests JSON deeper than {MAX_JSON_DEPTH} levels; got {shown!r}") from err
    except ValueError as err:  # JSONDecodeError, and int() refusing a number of more than 4300 digits
        raise ProtocolError(f"payload is not valid JSON ({err}); got {shown!r}") from err
    # A cheap bound first: nesting cannot exceed the number of opening brackets.
    if raw.count(b"[") + raw.count(b"{") > MAX_JSON_DEPTH and _too_deep(obj, MAX_JSON_DEPTH):
        raise ProtocolError(f"payload nests JSON deeper than {MAX_JSON_DEPTH} levels; got {shown!r}")
    return obj


def decode(
    data: bytes | bytearray | memoryview | str,
    max_bytes: int = MAX_PAYLOAD_BYTES,
    expected: str | None = None,
) -> WireMessage:
    """Decode any registered message (or only ``expected``); raise ProtocolError naming what is wrong."""
    raw = bytes(data, "utf-8") if isinstance(data, str) else bytes(data)
    if len(raw) > max_bytes:
        raise ProtocolError(f"payload of {len(raw)} bytes exceeds the limit of {max_bytes} bytes")
    obj = _parse(raw)
    if not isinstance(obj, dict):
        raise ProtocolError(f"payload must be a JSON object, got {type(obj).__name__}")
    kind = obj.get("type")
    if expected is not None and kind != expected:
        raise ProtocolError(f"expected a {expected} message, got type {kind!r}")
    model = MESSAGE_TYPES.get(kind) if isinstance(kind, str) else None
    if model is None:
        raise ProtocolError(f"message type {kind!r} is unknown; expected one of {sorted(MESSAGE_TYPES)}")
    version = obj.get("v")
    supported = model.model_fields["v"].default
    if isinstance(version, bool) or version != supported:  # true == 1 in Python, not on the wire
        raise ProtocolError(f"{kind} version {version!r} is not supported; this cellctl speaks version {supported}")
    try:
        return model.model_validate(obj)
    except ValidationError as err:
        raise ProtocolError(f"invalid {kind}: {_explain(err)}") from err


def peek_request_id(data: bytes | bytearray | memoryview | str, max_bytes: int = MAX_PAYLOAD_BYTES) -> str | None:
    """The ``request_id`` of a payload that may not decode as a message, when it can be read.

    Read with the same strict parser as :func:`decode`: a JSON object whose ``request_id`` is a
    string of at most :data:`MAX_REQUEST_ID_CHARS`; anything else gives None. Lets a reject of
    a wrong ``type``/``v`` still name the request it answers.
    """
    raw = bytes(data, "utf-8") if isinstance(data, str) else bytes(data)
    if len(raw) > max_bytes:
        return None
    try:
        obj = _parse(raw)
    except ProtocolError:
        return None
    rid = obj.get("request_id") if isinstance(obj, dict) else None
    if not isinstance(rid, str) or len(rid) > MAX_REQUEST_ID_CHARS:
        return None
    try:
        rid.encode("utf-8")  # JSON may spell a lone surrogate (\ud800): not text, and no Ack could carry it
    except UnicodeEncodeError:
        return None
    return rid


def decode_as(model: type[M], data: bytes | bytearray | memoryview | str, max_bytes: int = MAX_PAYLOAD_BYTES) -> M:
    """Decode and require a specific message type."""
    msg = decode(data, max_bytes, expected=model.model_fields["type"].default)
    assert isinstance(msg, model)
    return msg


def json_schemas() -> dict[str, dict[str, Any]]:
    """JSON Schema of every wire message, keyed by message type."""
    return {name: m.model_json_schema() for name, m in sorted(MESSAGE_TYPES.items())}
