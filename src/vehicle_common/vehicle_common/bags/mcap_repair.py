"""Repairing a scanned MCAP file (:func:`.mcap_scan.scan_mcap`): pure core, no rclpy.

:func:`repair_mcap` writes the file up to the end of its last complete chunk (in place or as a
copy), regenerates the last chunk's message indexes when they were cut (and the header when even
that was cut: an empty file), and appends a summary and footer, so that every MCAP reader
(mcap's ``make_reader``, rosbags) opens it. Nothing before the cut is rewritten. A file with
damaged chunks, or a summary that cannot be used, is written again without them
(:func:`_rewrite`: every other chunk kept byte for byte, message indexes and summary written
anew).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    MessageIndex,
    MetadataIndex,
    Statistics,
    SummaryOffset,
)

from .mcap_scan import MAGIC, McapRecoveryError, McapScan


def repair_mcap(scan: McapScan, dst: str | Path | None = None) -> Path:
    """Write the scanned file with a summary and footer: in place (``dst`` None: the file is cut
    after its last complete record and the summary appended) or as a copy at ``dst``. Returns
    the repaired file's path. A complete file is copied unchanged (or left as it is). A file
    with damaged chunks or a summary that cannot be used is written anew (:func:`_rewrite`)."""
    if scan.needs_rewrite:
        return _rewrite(scan, dst)
    src = scan.path
    if scan.complete:
        if dst is None:
            return src
        shutil.copyfile(src, dst)
        return Path(dst)
    end = scan.valid_end if scan.has_header else 0
    if scan.reindex_last:
        end = scan.chunks[-1].start + scan.chunks[-1].length
    scan.metadata = [m for m in scan.metadata if m[0] + m[1] <= end]
    target = Path(dst) if dst is not None else src
    if dst is not None:
        with open(src, "rb") as fin, open(target, "wb") as fout:
            remaining = end
            while remaining:
                buf = fin.read(min(remaining, 1 << 22))
                if not buf:
                    break
                fout.write(buf)
                remaining -= len(buf)
    with open(target, "r+b") as f:
        f.truncate(end)
        f.seek(end)
        f.write(_tail(scan, end))
        f.flush()
        os.fsync(f.fileno())
    return target


def _rewrite(scan: McapScan, dst: str | Path | None = None) -> Path:
    """Write the scanned file without its damaged chunks: every record kept as it is (each
    chunk followed by message indexes rebuilt from its data), then a new summary and footer.
    In place through a temporary file beside it (renamed over the original once on disk) or
    as a copy at ``dst``."""
    src = scan.path
    unknown = sorted({c for chunk in scan.chunks for c in chunk.index} - set(scan.channels))
    if unknown:
        raise McapRecoveryError(
            f"{src}: cannot repair: the definitions of channel(s) {unknown} were lost with the "
            "damaged part and the summary does not hold them"
        )
    target = Path(dst) if dst is not None else src
    tmp = target.with_name(target.name + ".rewrite")
    chunks = {c.start: c for c in scan.chunks}
    kept_metadata = {o: (n, m) for o, n, m in scan.metadata}
    scan.metadata = []
    with open(src, "rb") as fin, open(tmp, "wb") as fout:
        out = RecordBuilder()  # a header and every definition at the start of the data
        Header(profile="ros2", library="bag_recover").write(out)
        for record in (*scan.schemas.values(), *scan.channels.values()):
            record.write(out)
        fout.write(MAGIC + out.end())
        for start, length, opcode in scan.records:
            if opcode in (Opcode.HEADER, Opcode.MESSAGE_INDEX):
                continue  # written above; rebuilt after each chunk
            fin.seek(start)
            new_start = fout.tell()
            fout.write(fin.read(length))
            chunk = chunks.get(start)
            if chunk is not None:
                chunk.start = new_start
                out = RecordBuilder()
                chunk.index_records = {}
                for channel, entries in chunk.index.items():
                    chunk.index_records[channel] = new_start + length + out.count
                    MessageIndex(channel_id=channel, records=entries).write(out)
                fout.write(out.end())
                chunk.index_end = fout.tell()
            elif opcode == Opcode.METADATA and start in kept_metadata:
                n, meta = kept_metadata[start]
                scan.metadata.append((new_start, n, meta))
        end = fout.tell()
        scan.reindex_last = False
        scan.has_header = True
        fout.write(_tail(scan, end))
        fout.flush()
        os.fsync(fout.fileno())
    tmp.replace(target)
    return target


def _tail(scan: McapScan, end: int) -> bytes:
    """Message indexes of a cut last chunk, data end, summary, summary offsets, footer, magic."""
    head = b""
    if not scan.has_header:  # cut inside the magic or header: nothing survived, start anew
        hb = RecordBuilder()
        Header(profile="ros2", library="bag_recover").write(hb)
        head = MAGIC + hb.end()
    out = RecordBuilder()
    pos = end + len(head)
    if scan.reindex_last:
        last = scan.chunks[-1]
        last.index_records = {}
        for channel, entries in last.index.items():
            last.index_records[channel] = pos + out.count
            MessageIndex(channel_id=channel, records=entries).write(out)
        last.index_end = pos + out.count
    DataEnd(data_section_crc=0).write(out)
    summary_start = pos + out.count
    groups: list[tuple[int, int, int]] = []  # opcode, start, length

    def group(opcode, records) -> None:
        start = out.count
        for r in records:
            r.write(out)
        if out.count > start:
            groups.append((opcode, pos + start, out.count - start))

    group(Opcode.SCHEMA, scan.schemas.values())
    group(Opcode.CHANNEL, scan.channels.values())
    stats = Statistics(
        message_count=scan.message_count,
        schema_count=len(scan.schemas),
        channel_count=len(scan.channels),
        attachment_count=0,
        metadata_count=len(scan.metadata),
        chunk_count=len(scan.chunks),
        message_start_time=scan.start_time,
        message_end_time=scan.end_time,
        channel_message_counts=dict(scan.message_counts),
    )
    group(Opcode.STATISTICS, [stats])
    group(
        Opcode.CHUNK_INDEX,
        [
            ChunkIndex(
                message_start_time=c.message_start_time,
                message_end_time=c.message_end_time,
                chunk_start_offset=c.start,
                chunk_length=c.length,
                message_index_offsets=dict(c.index_records),
                message_index_length=c.index_end - (c.start + c.length),
                compression=c.compression,
                compressed_size=c.compressed_size,
                uncompressed_size=c.uncompressed_size,
            )
            for c in scan.chunks
        ],
    )
    group(
        Opcode.METADATA_INDEX,
        [MetadataIndex(offset=o, length=n, name=m.name) for o, n, m in scan.metadata],
    )
    summary_offset_start = pos + out.count
    for opcode, start, length in groups:
        SummaryOffset(group_opcode=opcode, group_start=start, group_length=length).write(out)
    Footer(
        summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=0
    ).write(out)
    return head + out.end() + MAGIC
