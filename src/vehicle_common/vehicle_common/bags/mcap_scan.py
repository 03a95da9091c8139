"""Scanning an MCAP file record by record, for a file that lost its end (recorder killed, power
cut) or holds a damaged chunk: pure core, no rclpy.

An MCAP file is written as a data section (header, schemas, channels, chunks of messages each
followed by its message indexes, metadata) and closed by a summary (schemas, channels,
statistics, chunk indexes) and a footer. A writer that dies leaves the data section only, cut
anywhere, maybe inside a chunk. :func:`scan_mcap` walks the top-level records and keeps every
record that is complete (chunks decompress and match their CRC); :mod:`.mcap_repair` then
writes the file up to the end of the last complete chunk with a summary and footer.

A damaged chunk inside the file (bytes flipped on a disk or in a copy: its CRC or its
compression fails, issue #42) is found by ``scan_mcap(past_damage=True)``, which notes it
(:class:`DamagedChunk`: where, why, its messages' times and, from the message indexes after it,
how many messages of which channel it held) and goes on with the next record. A file whose
summary cannot be read, or does not match its data (:func:`check_summary`), is marked to be
written again.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    Header,
    MessageIndex,
    Metadata,
    Schema,
)

MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"


class McapRecoveryError(ValueError):
    """The file is not an MCAP file, or nothing of it can be recovered; the message says why."""


@dataclass
class ChunkInfo:
    """A complete chunk: where it lies and what it holds (message indexes rebuilt from its data)."""

    start: int  # offset of the chunk record
    length: int  # record length including opcode and length prefix
    message_start_time: int
    message_end_time: int
    compression: str
    compressed_size: int
    uncompressed_size: int
    index: dict[int, list[tuple[int, int]]]  # channel id -> [(log time, offset in chunk)]
    index_records: dict[int, int] = field(default_factory=dict)  # channel -> file offset
    index_end: int = 0  # end of the message index records found after the chunk


@dataclass
class DamagedChunk:
    """A chunk record whose framing is intact but whose content is not (CRC mismatch, a
    compressed stream that does not decompress): its messages cannot be read."""

    start: int  # offset of the chunk record
    length: int  # record length including opcode and length prefix
    reason: str
    message_start_time: int | None = None  # from the chunk's header, when it could be read
    message_end_time: int | None = None
    lost: dict[int, int] = field(default_factory=dict)  # channel id -> messages (its indexes)

    @property
    def lost_count(self) -> int | None:
        """Messages the chunk held (None when its message indexes were not found)."""
        return sum(self.lost.values()) if self.lost else None


@dataclass
class McapScan:
    """What :func:`scan_mcap` found in one file."""

    path: Path
    size: int
    complete: bool  # footer and end magic present: the file needs no repair
    valid_end: int = 0  # bytes [0, valid_end) are kept by a repair
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunks: list[ChunkInfo] = field(default_factory=list)
    metadata: list[tuple[int, int, Metadata]] = field(default_factory=list)  # offset, length
    message_counts: dict[int, int] = field(default_factory=dict)  # channel id -> messages
    start_time: int = 0
    end_time: int = 0
    first_message: bytes = b""  # data of the first message (to detect per-message compression)
    has_header: bool = False  # the header record after the magic is complete
    reindex_last: bool = False  # the last chunk's message indexes were cut: write them again
    stop_reason: str = ""  # why the scan stopped before the end of the file
    damaged: list[DamagedChunk] = field(default_factory=list)  # skipped (past_damage)
    #: damaged schema, channel or message index records, left out (past_damage)
    skipped: list[str] = field(default_factory=list)
    #: (offset, length, opcode) of every record kept (not a damaged chunk or its indexes)
    records: list[tuple[int, int, int]] = field(default_factory=list)
    summary_bad: str = ""  # a complete file whose summary cannot be used: why

    @property
    def needs_rewrite(self) -> bool:
        """Damaged chunks or records to leave out, or a summary to write anew."""
        return bool(self.damaged or self.skipped or self.summary_bad)

    @property
    def message_count(self) -> int:
        return sum(self.message_counts.values())

    @property
    def lost_bytes(self) -> int:
        """Bytes after the last complete record (a chunk cut short, a partial index)."""
        return self.size - self.valid_end

    @property
    def messages_compressed(self) -> bool:
        """True when messages are zstd frames (rosbag2's per-message compression), not CDR."""
        return self.first_message[:4] == _ZSTD_MAGIC


def has_footer(path: str | Path) -> bool:
    """True when the file ends with an MCAP footer record and the closing magic."""
    path = Path(path)
    size = path.stat().st_size
    if size < 8 + 9 + 20 + 8:
        return False
    with open(path, "rb") as f:
        f.seek(size - 37)
        tail = f.read(37)
    return tail[-8:] == MAGIC and tail[0] == Opcode.FOOTER


def _chunk_index(chunk: Chunk, validate_crc: bool = True):
    """(message index, uncompressed data) of a chunk: index is channel -> [(log time, offset of
    the message record)]; raises ValueError when the chunk is damaged."""
    if chunk.compression == "zstd":
        import zstandard

        data = zstandard.decompress(chunk.data, chunk.uncompressed_size)
    elif chunk.compression == "lz4":
        import lz4.frame

        data = lz4.frame.decompress(chunk.data)
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise ValueError(f"unknown chunk compression {chunk.compression!r}")
    if len(data) != chunk.uncompressed_size:
        raise ValueError("chunk size does not match its header")
    if validate_crc and chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise ValueError("chunk CRC mismatch")
    index: dict[int, list[tuple[int, int]]] = {}
    pos = 0
    while pos < len(data):
        opcode, length = _RECORD_HEAD.unpack_from(data, pos)
        if pos + 9 + length > len(data):
            raise ValueError("record overruns its chunk")
        if opcode == Opcode.MESSAGE:
            channel, _seq, log_time, _pub = _MESSAGE_HEAD.unpack_from(data, pos + 9)
            index.setdefault(channel, []).append((log_time, pos))
        pos += 9 + length
    return index, data


def scan_mcap(
    path: str | Path, past_damage: bool = False, resume: list[int] | None = None
) -> McapScan:
    """Walk the file's top-level records up to the first incomplete or damaged one;
    ``past_damage``: a damaged chunk whose record is complete is noted (``scan.damaged``) and
    the walk goes on after it. ``resume``: offsets of records (the summary's chunk indexes)
    where the walk goes on when a record's framing itself is damaged (noted in
    ``scan.skipped``)."""
    path = Path(path)
    size = path.stat().st_size
    scan = McapScan(path=path, size=size, complete=has_footer(path))
    with open(path, "rb") as f:
        magic = f.read(8)
        if magic != MAGIC:
            if MAGIC.startswith(magic):  # killed before even the magic was written: empty
                scan.stop_reason = "file cut inside its magic"
                return scan
            raise McapRecoveryError(f"{path}: cannot read bag (not an MCAP file: bad magic)")
        _RecordWalk(f, scan, past_damage, resume).run()
    times = [t for c in scan.chunks for entries in c.index.values() for t, _ in entries]
    if times:
        scan.start_time, scan.end_time = min(times), max(times)
    if scan.chunks:
        last = scan.chunks[-1]
        scan.reindex_last = set(last.index_records) != set(last.index)
    return scan


class _RecordWalk:
    """:func:`scan_mcap`'s walk over the top-level records after the magic: ``pos`` is the
    offset of the next record, ``bad`` the damaged chunk just passed (its message indexes
    follow it and say what it held)."""

    def __init__(self, f, scan: McapScan, past_damage: bool, resume: list[int] | None) -> None:
        self.f, self.scan = f, scan
        self.past_damage, self.resume = past_damage, resume
        self.pos = scan.valid_end = 8
        self.bad: DamagedChunk | None = None

    def run(self) -> None:
        """Read records until the end of the data section, an incomplete record or damage
        that cannot be passed (``scan.stop_reason`` says which)."""
        scan = self.scan
        while True:
            head = self.f.read(9)
            if len(head) < 9:
                scan.stop_reason = "" if not head else "incomplete record"
                return
            opcode, length = _RECORD_HEAD.unpack(head)
            if self.pos + 9 + length > scan.size:
                if not (scan.complete and self.past_damage):
                    scan.stop_reason = "incomplete record"
                    return
                # a complete file: its framing is damaged
                exc = ValueError(f"record length {length} runs past the end of the file")
                if not self._resume(exc):
                    return
                continue
            content = self.f.read(length)
            rec_len = 9 + length
            if opcode != Opcode.MESSAGE_INDEX:
                self.bad = None
            try:
                if self.bad is not None:  # an index of the damaged chunk: what it held
                    mi = MessageIndex.read(ReadDataStream(BytesIO(content)))
                    lost = self.bad.lost
                    lost[mi.channel_id] = lost.get(mi.channel_id, 0) + len(mi.records)
                    self._advance(rec_len)
                    continue
                if _read_record(scan, opcode, content, self.pos, rec_len):
                    return  # the end of the data section
            except Exception as exc:  # damaged record: the data ends before it
                if not self._pass_damage(opcode, content, rec_len, exc):
                    return
                continue
            scan.records.append((self.pos, rec_len, opcode))
            self._advance(rec_len)

    def _advance(self, rec_len: int) -> None:
        self.pos += rec_len
        self.scan.valid_end = self.pos

    def _resume(self, exc: Exception) -> bool:
        """Go on at the next offset of ``resume`` after a record whose framing is damaged
        (:func:`_go_on`); False: the walk stops."""
        if not _go_on(self.scan, self.f, self.pos, exc, self.resume):
            return False
        self.pos, self.bad = self.scan.valid_end, None
        return True

    def _pass_damage(self, opcode: int, content: bytes, rec_len: int, exc: Exception) -> bool:
        """After a record that failed to read: with ``past_damage`` a damaged chunk is noted
        and a schema, channel or index left out (the summary's copy or a rebuilt one stands
        in); else go on at ``resume``. False: the walk stops."""
        if self.past_damage and opcode == Opcode.CHUNK:
            self.bad = _damaged_chunk(content, self.pos, rec_len, exc)
            self.scan.damaged.append(self.bad)
            self._advance(rec_len)
            return True
        if self.past_damage and opcode in _REBUILT:
            self.scan.skipped.append(f"record at byte {self.pos} ({exc or type(exc).__name__})")
            self._advance(rec_len)
            return True
        return self._resume(exc)


def _read_record(scan: McapScan, opcode: int, content: bytes, pos: int, rec_len: int) -> bool:
    """Note one complete top-level record at ``pos`` in ``scan``; True at the data end.
    Raises (ValueError, or mcap's and the decompressors' errors) when it is damaged."""
    stream = ReadDataStream(BytesIO(content))
    if opcode == Opcode.HEADER and pos == 8:
        Header.read(stream)
        scan.has_header = True
    elif opcode == Opcode.SCHEMA:
        s = _checked_schema(Schema.read(stream))
        scan.schemas[s.id] = s
    elif opcode == Opcode.CHANNEL:
        c = Channel.read(stream)
        scan.channels[c.id] = c
    elif opcode == Opcode.CHUNK:
        _read_chunk(scan, Chunk.read(stream), pos, rec_len)
    elif opcode == Opcode.MESSAGE_INDEX:
        mi = MessageIndex.read(stream)
        if not scan.chunks:
            raise ValueError("message index before any chunk")
        scan.chunks[-1].index_records[mi.channel_id] = pos
        scan.chunks[-1].index_end = pos + rec_len
    elif opcode == Opcode.METADATA:
        scan.metadata.append((pos, rec_len, Metadata.read(stream)))
    elif opcode == Opcode.DATA_END:
        scan.stop_reason = "end of data section"
        return True
    elif opcode in (Opcode.HEADER, Opcode.FOOTER) or opcode == 0:
        raise ValueError(f"unexpected record 0x{opcode:02x}")
    # attachments, top-level messages and unknown records are kept as they are
    return False


def _read_chunk(scan: McapScan, chunk: Chunk, pos: int, rec_len: int) -> None:
    """A complete chunk at ``pos``: decompressed and CRC-checked (ValueError when damaged),
    its schemas, channels, message index and counts noted."""
    index, data = _chunk_index(chunk)
    _inner_schemas_channels(data, scan)
    scan.chunks.append(
        ChunkInfo(
            start=pos,
            length=rec_len,
            message_start_time=chunk.message_start_time,
            message_end_time=chunk.message_end_time,
            compression=chunk.compression,
            compressed_size=len(chunk.data),
            uncompressed_size=chunk.uncompressed_size,
            index=index,
        )
    )
    scan.chunks[-1].index_end = pos + rec_len
    for channel, entries in index.items():
        scan.message_counts[channel] = scan.message_counts.get(channel, 0) + len(entries)
    if not scan.first_message and index:
        off = min(o for entries in index.values() for _, o in entries)
        scan.first_message = data[off + 9 + _MESSAGE_HEAD.size :][:4]


#: top-level records a rewrite can do without: a schema or channel (also in the summary), a
#: message index (rebuilt from its chunk)
_REBUILT = (Opcode.HEADER, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE_INDEX)
#: schema encodings whose data is text
_TEXT_SCHEMAS = ("ros2msg", "ros2idl", "ros1msg", "jsonschema", "omgidl")


def _checked_schema(schema: Schema) -> Schema:
    """``schema``; ValueError when its text is not UTF-8 (bytes flipped in it: rosbags then
    fails to open the file with a UnicodeDecodeError)."""
    if schema.encoding in _TEXT_SCHEMAS:
        try:
            schema.data.decode()
        except UnicodeDecodeError:
            raise ValueError(f"schema {schema.id} text is not UTF-8") from None
    return schema


def _go_on(scan: McapScan, f, pos: int, exc: Exception, resume: list[int] | None) -> bool:
    """After a record at ``pos`` whose framing is damaged: True (``f`` and ``scan.valid_end``
    at the next offset of ``resume``, the bytes between noted in ``scan.skipped``) when there
    is one, else False with ``scan.stop_reason`` set."""
    why = str(exc) or type(exc).__name__
    later = [o for o in resume or () if o > pos]
    if not later:
        scan.stop_reason = f"damaged record at byte {pos} ({why})"
        return False
    scan.skipped.append(f"bytes {pos}-{later[0]} ({why})")
    f.seek(later[0])
    scan.valid_end = later[0]
    return True


def _damaged_chunk(content: bytes, pos: int, rec_len: int, exc: Exception) -> DamagedChunk:
    """A :class:`DamagedChunk` for the chunk record at ``pos`` (its header's times when the
    header itself can be read)."""
    reason = str(exc) or type(exc).__name__
    bad = DamagedChunk(start=pos, length=rec_len, reason=reason)
    if len(content) >= 16:
        start, end = struct.unpack_from("<QQ", content, 0)
        if start <= end:
            bad.message_start_time, bad.message_end_time = start, end
    return bad


def summary_chunk_offsets(path: str | Path) -> list[int]:
    """Offsets of the chunks the file's summary indexes ([] when it cannot be read)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
        return sorted(c.chunk_start_offset for c in summary.chunk_indexes) if summary else []
    except Exception:  # noqa: BLE001 (a damaged summary: no offsets to go on at)
        return []


def check_summary(scan: McapScan) -> None:
    """Set ``scan.summary_bad`` when the complete file's summary cannot be read or does not
    match what its data section holds (message and chunk counts)."""
    if not scan.complete:
        return
    from mcap.reader import make_reader

    try:
        with open(scan.path, "rb") as f:
            summary = make_reader(f).get_summary()
    except Exception as exc:  # noqa: BLE001 (mcap raises several types for a damaged summary)
        scan.summary_bad = f"summary unreadable ({exc or type(exc).__name__})"
        return
    if summary is None:
        scan.summary_bad = "no summary"
        return
    for sid, schema in summary.schemas.items():  # definitions only a damaged part held
        try:
            scan.schemas.setdefault(sid, _checked_schema(schema))
        except ValueError as exc:
            scan.summary_bad = f"summary {exc}"
    for cid, channel in summary.channels.items():
        scan.channels.setdefault(cid, channel)
    if scan.damaged or scan.summary_bad:
        return
    stats = summary.statistics
    indexed = sorted((c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes)
    if stats is None:
        scan.summary_bad = "no summary statistics"
    elif (stats.message_count, dict(stats.channel_message_counts)) != (
        scan.message_count,
        scan.message_counts,
    ):
        scan.summary_bad = (
            f"summary counts {stats.message_count} messages, the data {scan.message_count}"
        )
    elif indexed != sorted((c.start, c.length) for c in scan.chunks):
        scan.summary_bad = "summary chunk indexes do not match the chunks"
    elif any(summary.schemas[i].data != scan.schemas[i].data for i in summary.schemas):
        scan.summary_bad = "summary schemas differ from the data's"


def _inner_schemas_channels(data: bytes, scan: McapScan) -> None:
    """Schemas and channels written inside a chunk (mcap's writer puts them there)."""
    pos = 0
    while pos < len(data):
        opcode, length = _RECORD_HEAD.unpack_from(data, pos)
        if opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
            stream = ReadDataStream(BytesIO(data[pos + 9 : pos + 9 + length]))
            if opcode == Opcode.SCHEMA:
                s = _checked_schema(Schema.read(stream))
                scan.schemas[s.id] = s
            else:
                c = Channel.read(stream)
                scan.channels[c.id] = c
        pos += 9 + length
