"""JSON codec for the versioned wire messages of :mod:`cellctl.messages`."""

from __future__ import annotations

import json
from typing import TypeVar

from pydantic import ValidationError

from cellctl.errors import ProtocolError
from cellctl.messages import MESSAGE_TYPES, WireMessage

__all__ = ["MAX_PAYLOAD_BYTES", "decode", "decode_as", "encode", "json_schemas"]

MAX_PAYLOAD_BYTES = 64 * 1024
"""Largest control payload accepted; images travel separately and are not decoded here."""

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


def decode(
    data: bytes | bytearray | memoryview | str,
    max_bytes: int = MAX_PAYLOAD_BYTES,
    expected: str | None = None,
) -> WireMessage:
    """Decode any registered message (or only ``expected``); raise ProtocolError naming what is wrong."""
    raw = bytes(data, "utf-8") if isinstance(data, str) else bytes(data)
    if len(raw) > max_bytes:
        raise ProtocolError(f"payload of {len(raw)} bytes exceeds the limit of {max_bytes} bytes")
    try:
        obj = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        shown = raw[:60]
        raise ProtocolError(f"payload is not valid JSON ({err}); got {shown!r}") from err
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
    if version != supported:
        raise ProtocolError(f"{kind} version {version!r} is not supported; this cellctl speaks version {supported}")
    try:
        return model.model_validate(obj)
    except ValidationError as err:
        raise ProtocolError(f"invalid {kind}: {_explain(err)}") from err


def decode_as(model: type[M], data: bytes | bytearray | memoryview | str, max_bytes: int = MAX_PAYLOAD_BYTES) -> M:
    """Decode and require a specific message type."""
    msg = decode(data, max_bytes, expected=model.model_fields["type"].default)
    assert isinstance(msg, model)
    return msg


def json_schemas() -> dict[str, dict]:
    """JSON Schema of every wire message, keyed by message type."""
    return {name: m.model_json_schema() for name, m in sorted(MESSAGE_TYPES.items())}
