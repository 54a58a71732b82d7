"""Request/reply over Zenoh queries with explicit timeouts.

Three failures are told apart, because an operator acts differently on each:

* no reply at all, immediately → :class:`WorkerUnavailable` (nobody serves the key);
* a ``Timeout`` error reply after ``timeout`` → :class:`WorkerTimeout` (worker hung);
* an error reply from the worker → :class:`WorkerFailed` with the worker's reason.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeVar

import zenoh

from cellctl.bus.codec import decode, decode_as, encode
from cellctl.errors import ProtocolError, WorkerFailed, WorkerTimeout, WorkerUnavailable
from cellctl.messages import ErrorReply, WireMessage

__all__ = ["Reply", "request"]

M = TypeVar("M", bound=WireMessage)

MAX_REPLY_META_BYTES = 4 * 1024 * 1024


@dataclass(frozen=True)
class Reply:
    """A decoded reply: the message and, for image replies, the raw payload bytes."""

    message: WireMessage
    payload: bytes | None = None


def _err_text(err: zenoh.ReplyError | None) -> str:
    if err is None:
        return "<unreadable error payload>"
    try:
        return err.payload.to_bytes().decode("utf-8", "replace")
    except Exception:  # a reply error without a readable payload
        return "<unreadable error payload>"


def request(
    session: zenoh.Session,
    key: str,
    msg: WireMessage,
    expect: type[M],
    *,
    timeout: float,
    payload: bytes | None = None,
    role: str | None = None,
) -> tuple[M, bytes | None]:
    """Send ``msg`` to the one worker serving ``key`` and return its typed reply.

    When ``payload`` is given (an encoded image), it is the query payload and ``msg`` travels
    as the attachment; replies may do the same (image replies), in which case the raw
    payload is returned beside the message.

    Blocks up to ``timeout`` seconds.

    Raises:
        WorkerUnavailable: no worker serves ``key``.
        WorkerTimeout: the worker did not answer within ``timeout``.
        WorkerFailed: the worker replied with an error (its reason is in the message).
        ProtocolError: the reply is not the expected message (type, version, fields), or more
            than one reply came back; the message names the role and the op.
    """
    op = key.rsplit("/", 1)[-1]
    body = encode(msg)
    # No consolidation: Zenoh would otherwise keep only the last of several replies, silently.
    # A raw payload (an image) travels as the payload, the request as the attachment.
    replies = list(
        session.get(
            key,
            timeout=timeout,
            target=zenoh.QueryTarget.BEST_MATCHING,
            consolidation=zenoh.ConsolidationMode.NONE,
            payload=body if payload is None else payload,
            attachment=None if payload is None else body,
        )
    )
    if not replies:
        raise WorkerUnavailable(
            f"no {role or 'worker'} serves {key!r} (0 replies: nobody serves it, or the worker dropped the query)",
            role=role,
            op=op,
        )
    if len(replies) > 1:
        # One queryable answers one query once; more means a misbehaving worker or two workers on one key.
        raise ProtocolError(f"{role or 'worker'} answered {op} with {len(replies)} replies; expected exactly one")
    rep = replies[0]
    if rep.ok is None:
        text = _err_text(rep.err)
        if text.strip().lower() == "timeout":
            raise WorkerTimeout(
                f"{role or 'worker'} did not answer {key!r} within {timeout:g} s (hung?)", role=role, op=op
            )
        try:
            err = decode_as(ErrorReply, text)
            raise WorkerFailed(f"{role or 'worker'} refused {op}: {err.reason}", role=role, op=op)
        except ProtocolError:
            # not an ErrorReply: show it, escaped when it is not plain text (it goes into logs and Status)
            shown = text[:300] if text[:300].isprintable() else repr(text[:300])
            raise WorkerFailed(
                f"{role or 'worker'} failed {op}: {shown or '(empty error reply)'}", role=role, op=op
            ) from None
    sample = rep.ok
    data = sample.payload.to_bytes()
    att = sample.attachment.to_bytes() if sample.attachment is not None else None
    try:
        meta = decode(att if att is not None else data, MAX_REPLY_META_BYTES)
    except ProtocolError as err:
        raise ProtocolError(f"{role or 'worker'} answered {op} with an unusable reply: {err}") from err
    raw = data if att is not None else None
    if not isinstance(meta, expect):
        raise ProtocolError(
            f"{role or 'worker'} answered {op} with {meta.type}, expected {expect.model_fields['type'].default}"
        )
    return meta, raw
