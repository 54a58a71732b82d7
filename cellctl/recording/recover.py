"""Recover a cut-short MCAP (a writer killed mid-cycle) into a valid, indexed one, as ``mcap recover`` does.

A cycle log killed mid-write holds every record up to the crash but no summary and no footer,
so an indexed reader (``mcap.reader.make_reader(f).get_summary()``, viewers that index first)
reads the last bytes as a footer and refuses the file. Recovery reads the records in order
until the first one that is cut short or unreadable, and writes every complete schema,
channel, message, attachment and metadata record into a new chunked file with chunk indexes,
a summary and a footer. The source is only read, never changed: it stays the evidence.

Where the cut falls inside a chunk, the chunk's complete inner records are kept too (an
uncompressed chunk exactly; a zstd or lz4 one as far as its compressed prefix decodes).

The output is a function of the source bytes alone (fixed header, no clock), so recovering
the same source twice gives byte-identical files.
"""

from __future__ import annotations

import logging
import os
import struct
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from io import BytesIO
from pathlib import Path
from typing import IO

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, Footer, Header, McapRecord, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer

from cellctl import __version__
from cellctl.errors import RecordingError
from cellctl.hashing import bytes_sha256

__all__ = ["RECOVERED_SUFFIX", "Recovery", "recover_mcap", "recovered_path"]

log = logging.getLogger(__name__)
log.addHandler(logging.NullHandler())

MCAP_MAGIC = b"\x89MCAP0\r\n"
RECOVERED_SUFFIX = ".recovered.mcap"
"""``<cycle_id>.mcap`` is recovered into ``<cycle_id>.recovered.mcap`` beside it."""

_RECORD_HEAD = struct.Struct("<BQ")  # opcode, content length
# Chunk content up to its records: start/end time, uncompressed size, crc, compression name length.
_CHUNK_HEAD = struct.Struct("<QQQII")


@dataclass(frozen=True)
class Recovery:
    """What :func:`recover_mcap` found and wrote; ``intact_bytes`` is where the source was cut."""

    source: str
    source_sha256: str
    source_bytes: int
    intact_bytes: int
    """Length of the source's prefix made of complete records (magic included): the cut."""
    had_footer: bool
    """The source was complete (footer and closing magic); nothing was cut."""
    stopped: str | None
    """Why reading stopped before the footer (the cut record, or unreadable bytes), else None."""
    out: str
    out_sha256: str
    messages: int
    schemas: int
    channels: int
    attachments: int
    metadata: int
    from_cut_chunk: int
    """Messages kept from the complete part of a chunk the cut fell into (included in ``messages``)."""

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


def recovered_path(log_path: Path | str) -> Path:
    """Where the recovered copy of ``log_path`` goes: beside it, ``<stem>.recovered.mcap``."""
    p = Path(log_path)
    stem = p.name[: -len(".mcap")] if p.name.endswith(".mcap") else p.name
    return p.with_name(stem + RECOVERED_SUFFIX)


class _Cut(Exception):
    """Reading stopped: the record at ``offset`` is cut short or unreadable (``why``)."""

    def __init__(self, offset: int, why: str) -> None:
        super().__init__(why)
        self.offset = offset
        self.why = why


# The mcap library's own record readers, for the records a recovered file keeps; the others
# (indexes, statistics, data end) are rebuilt by the writer.
_READERS = {
    Opcode.HEADER: Header.read,
    Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read,
    Opcode.CHUNK: Chunk.read,
    Opcode.ATTACHMENT: Attachment.read,
    Opcode.METADATA: Metadata.read,
    Opcode.FOOTER: Footer.read,
}


def _parse(opcode: int, content: bytes) -> McapRecord | None:
    stream = ReadDataStream(BytesIO(content))
    if opcode == Opcode.MESSAGE:
        return Message.read(stream, len(content))
    reader = _READERS.get(opcode)  # type: ignore[call-overload]
    return reader(stream) if reader else None


def _lex(data: bytes, start: int) -> Iterator[tuple[int, int, McapRecord | None]]:
    """Records of ``data`` from ``start`` as (start, end, record); raises _Cut at the first bad one."""
    pos = start
    while pos < len(data):
        if len(data) - pos < _RECORD_HEAD.size:
            raise _Cut(pos, f"a record header cut after {len(data) - pos} of {_RECORD_HEAD.size} bytes")
        opcode, length = _RECORD_HEAD.unpack_from(data, pos)
        if opcode == 0:
            raise _Cut(pos, "opcode 0 (not a record: the bytes are garbage)")
        end = pos + _RECORD_HEAD.size + length
        if end > len(data):
            have = len(data) - pos - _RECORD_HEAD.size
            raise _Cut(pos, f"a {_name(opcode)} record of {length} bytes cut after {have} bytes")
        try:
            rec = _parse(opcode, data[pos + _RECORD_HEAD.size : end])
        except Exception as err:  # any parse failure means garbage: stop here
            raise _Cut(pos, f"an unreadable {_name(opcode)} record: {type(err).__name__}: {err}") from err
        yield pos, end, rec
        pos = end


def _name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower()
    except ValueError:
        return f"unknown (opcode {opcode:#x})"


def _cut_chunk_records(content: bytes) -> tuple[bytes, str]:
    """The decodable prefix of a cut chunk's records, and its compression."""
    if len(content) < _CHUNK_HEAD.size:
        return b"", "?"
    *_, name_len = _CHUNK_HEAD.unpack_from(content, 0)
    at = _CHUNK_HEAD.size
    compression = content[at : at + name_len].decode("utf-8", "replace")
    body = content[at + name_len + 8 :]  # after the records length
    try:
        if compression == "":
            return body, compression
        if compression == "zstd":
            import zstandard

            return zstandard.ZstdDecompressor().decompressobj().decompress(body), compression
        if compression == "lz4":
            import lz4.frame

            return lz4.frame.LZ4FrameDecompressor().decompress(body), compression
    except Exception as err:  # an undecodable tail keeps nothing of this chunk
        log.info("cut %s chunk does not decode: %s", compression, err)
    return b"", compression


class _Copier:
    """Feeds records to a Writer, renumbering schema and channel ids in first-seen order."""

    def __init__(self, writer: Writer) -> None:
        self.writer = writer
        self.schema_ids: dict[int, int] = {0: 0}
        self.channel_ids: dict[int, int] = {}
        self.messages = self.attachments = self.metadata = 0
        self.unknown_channel = 0

    def add(self, rec: McapRecord | None) -> None:
        w = self.writer
        if isinstance(rec, Schema):
            if rec.id not in self.schema_ids:  # the summary repeats schemas: keep the first
                self.schema_ids[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
        elif isinstance(rec, Channel):
            if rec.id not in self.channel_ids and rec.schema_id in self.schema_ids:
                self.channel_ids[rec.id] = w.register_channel(
                    rec.topic, rec.message_encoding, self.schema_ids[rec.schema_id], dict(rec.metadata)
                )
        elif isinstance(rec, Message):
            cid = self.channel_ids.get(rec.channel_id)
            if cid is None:
                self.unknown_channel += 1  # its channel record was lost: undecodable, not copied
                return
            w.add_message(cid, rec.log_time, bytes(rec.data), rec.publish_time, rec.sequence)
            self.messages += 1
        elif isinstance(rec, Attachment):
            w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, bytes(rec.data))
            self.attachments += 1
        elif isinstance(rec, Metadata):
            w.add_metadata(rec.name, dict(rec.metadata))
            self.metadata += 1


def _records(data: bytes) -> Iterator[tuple[int, McapRecord | None]]:
    """(end offset, record) of the top-level records after the magic, chunks broken up into their
    inner records; raises _Cut at the first record that is cut short or garbage."""
    for start, end, rec in _lex(data, len(MCAP_MAGIC)):
        if isinstance(rec, Chunk):
            try:
                inner = breakup_chunk(rec, validate_crc=True)
            except Exception as err:  # a chunk that fails its CRC is garbage
                raise _Cut(start, f"a chunk whose records do not decode: {type(err).__name__}: {err}") from err
            for r in inner:
                yield end, r
        else:
            yield end, rec


def _cut_chunk_messages(data: bytes, offset: int, copier: _Copier) -> str:
    """Copy the complete inner records of the chunk cut at ``offset``; say how many messages."""
    body, compression = _cut_chunk_records(data[offset + _RECORD_HEAD.size :])
    before = copier.messages
    try:
        for _, _, r in _lex(body, 0):
            copier.add(r)
    except _Cut:
        pass  # the complete inner records are all there is
    return f"{copier.messages - before} complete message(s) kept from the cut {compression or 'uncompressed'} chunk"


def recover_mcap(source: Path | str, out: Path | str | None = None) -> Recovery:
    """Write every complete record of ``source`` into ``out``, a valid indexed MCAP.

    Blocking; holds the source and the output in memory (a cycle log is tens of MB at most)
    and never writes to the source. ``out`` is written to a temporary name and renamed into
    place, so a crash during recovery leaves no half file under the final name.

    Args:
        source: an MCAP file, complete or cut short at any byte.
        out: where to write; default :func:`recovered_path` of ``source``.

    Returns:
        What was recovered and where the source was cut.

    Raises:
        RecordingError: the source cannot be read, does not start like an MCAP file, or ``out``
            is the source or cannot be written.
    """
    src = Path(source)
    dst = Path(out) if out is not None else recovered_path(src)
    try:
        data = src.read_bytes()
    except OSError as err:
        raise RecordingError(f"cannot read {str(src)!r}: {err}") from err
    if dst.resolve() == src.resolve():
        raise RecordingError(f"recovery output {str(dst)!r} is the source itself; expected another path")
    head = data[: len(MCAP_MAGIC)]
    # A file cut inside the magic is a prefix of it: recovered, with nothing to keep.
    if not MCAP_MAGIC.startswith(head):
        raise RecordingError(
            f"{str(src)!r} is not an MCAP file (starts with {head!r}, expected {MCAP_MAGIC!r}); nothing to recover"
        )
    buf = BytesIO()
    found = _recover_into(data, src, buf)
    out_bytes = buf.getvalue()
    tmp = dst.with_name(dst.name + ".part")
    try:
        dst.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            f.write(out_bytes)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, dst)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        raise RecordingError(f"cannot write the recovered log {str(dst)!r}: {err}") from err
    # Both hashes from the bytes in hand: the source as recovered, the output as written.
    result = Recovery(
        source=str(src),
        source_sha256=bytes_sha256(data),
        source_bytes=len(data),
        out=str(dst),
        out_sha256=bytes_sha256(out_bytes),
        **found,  # type: ignore[arg-type]
    )
    log.info(
        "recovered %d messages of %s (cut at byte %d of %d) into %s",
        result.messages,
        src,
        result.intact_bytes,
        result.source_bytes,
        dst,
    )
    return result


def _recover_into(data: bytes, src: Path, f: IO[bytes]) -> dict[str, object]:
    writer = Writer(f, compression=CompressionType.ZSTD)
    copier = _Copier(writer)
    header: Header | None = None
    intact = len(MCAP_MAGIC) if data.startswith(MCAP_MAGIC) else 0
    stopped: str | None = None
    had_footer = False
    in_cut_chunk = 0

    def start(h: Header | None) -> None:
        library = f"{h.library if h else ''} (recovered by cellctl/{__version__})".strip()
        writer.start(profile=h.profile if h else "", library=library)

    if len(data) < len(MCAP_MAGIC):
        stopped = f"the file ends inside the magic ({len(data)} of {len(MCAP_MAGIC)} bytes)"
    else:
        try:
            for end, rec in _records(data):
                if header is None:
                    # MCAP opens with the Header; a file that does not still gets its records copied
                    header = rec if isinstance(rec, Header) else Header("", "")
                    start(header)
                    if isinstance(rec, Header):
                        intact = end
                        continue
                if isinstance(rec, Footer):
                    if data[end : end + len(MCAP_MAGIC)] == MCAP_MAGIC:
                        had_footer, intact = True, end + len(MCAP_MAGIC)
                    else:
                        intact, stopped = end, f"byte {end} of {len(data)}: the closing magic is missing"
                    break
                copier.add(rec)
                intact = end
            else:
                stopped = f"byte {intact} of {len(data)}: the file ends without a footer"
        except _Cut as cut:
            stopped = f"byte {cut.offset} of {len(data)}: {cut.why}"
            if data[cut.offset] == Opcode.CHUNK and header is not None:
                before = copier.messages
                stopped += "; " + _cut_chunk_messages(data, cut.offset, copier)
                in_cut_chunk = copier.messages - before
    if header is None:
        start(None)
    writer.add_metadata(
        "recovery",
        {
            "source": src.name,
            "source_bytes": str(len(data)),
            "intact_bytes": str(intact),
            "stopped": stopped or "",
            "recovered_by": f"cellctl/{__version__}",
        },
    )
    writer.finish()
    return {
        "intact_bytes": intact,
        "had_footer": had_footer,
        "stopped": stopped,
        "messages": copier.messages,
        "schemas": len(copier.schema_ids) - 1,
        "channels": len(copier.channel_ids),
        "attachments": copier.attachments,
        "metadata": copier.metadata,
        "from_cut_chunk": in_cut_chunk,
    }
