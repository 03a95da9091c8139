"""rosbag2 bags (MCAP storage) after a crash: ``metadata.yaml`` and reindexing (``bag_recover``).

A recorder that dies leaves a bag directory with no ``metadata.yaml`` and a last ``.mcap`` file
cut after its last flushed chunk (:mod:`.mcap_scan` and :mod:`.mcap_repair` handle one file).
This module works on the whole bag: it finds the split files (``<bag>_<i>.mcap``, rosbag2's
names), reindexes the cut one, and writes ``metadata.yaml`` from what the files hold
(:mod:`.metadata`, which also serves :class:`.writer.BagWriter` for bags closed normally), so
that rosbags' ``AnyReader``, mcap's ``make_reader``, rosbag2 and this project's tools open it.

:func:`recover_bag` repairs in place (the ``bag_recover`` console script);
:func:`readable_copy` builds a repaired view in a temporary folder without touching the bag
(for reading an interrupted recording).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from .mcap_repair import repair_mcap
from .mcap_scan import (
    McapRecoveryError,
    McapScan,
    check_summary,
    has_footer,
    scan_mcap,
    summary_chunk_offsets,
)
from .metadata import FileInfo, compress_file, rosbag2_metadata, write_metadata_yaml


class BagRecoveryError(McapRecoveryError):
    """The bag cannot be recovered; the message names the file and why."""


def split_index(bag_dir: Path, name: str) -> int | None:
    """``i`` of rosbag2's split name ``<bag>_<i>.mcap[.zstd]``, else None."""
    m = re.fullmatch(re.escape(bag_dir.name) + r"_(\d+)\.mcap(\.zstd)?", name)
    return int(m.group(1)) if m else None


def bag_files(bag_dir: str | Path) -> list[Path]:
    """The ``.mcap`` files of a bag directory without ``metadata.yaml``: rosbag2's split names
    in split order, else a single ``.mcap``. Raises BagRecoveryError when ambiguous."""
    bag_dir = Path(bag_dir)
    splits: dict[int, Path] = {}
    for p in sorted(bag_dir.iterdir()):  # x.mcap sorts before x.mcap.zstd
        i = split_index(bag_dir, p.name)
        if i is not None and p.is_file():
            splits[i] = p  # both present: compression finished, the .zstd one is complete
    if splits:
        return [splits[i] for i in sorted(splits)]
    mcaps = sorted(bag_dir.glob("*.mcap"))
    if len(mcaps) != 1:
        raise BagRecoveryError(
            f"{bag_dir}: not a rosbag2 directory (no metadata.yaml and {len(mcaps)} .mcap "
            f"files instead of one or {bag_dir.name}_<i>.mcap splits)"
        )
    return mcaps


def _decompressed(path: Path, tmp_dir: Path) -> Path:
    """A ``.mcap.zstd`` file (rosbag2 file compression) decompressed into ``tmp_dir``."""
    import zstandard

    out = tmp_dir / path.name[: -len(".zstd")]
    with open(path, "rb") as fin, open(out, "wb") as fout:
        try:
            zstandard.ZstdDecompressor().copy_stream(fin, fout)
        except zstandard.ZstdError as exc:
            raise BagRecoveryError(
                f"{path}: damaged: its zstd stream does not decompress ({exc})"
            ) from None
    return out


def file_info(path: Path, name: str | None = None, verify: bool = False) -> FileInfo:
    """Summarise one ``.mcap`` file: from its summary when complete, by scanning when cut (a
    damaged chunk is noted and passed: ``info.scan.damaged``). ``verify``: a complete file is
    scanned too (every chunk decompressed and its CRC checked, the summary compared with the
    data); one that fails gets ``info.scan`` (to repair) as a cut file does."""
    info = FileInfo(name=name or path.name)
    scan = None
    if verify and has_footer(path):
        scan = scan_mcap(path, past_damage=True)
        if _stopped_early(scan):  # a record's framing is damaged: go on at the next chunk
            scan = scan_mcap(path, past_damage=True, resume=summary_chunk_offsets(path))
        check_summary(scan)
        if not scan.needs_rewrite and not _stopped_early(scan):
            scan = None
    if has_footer(path) and scan is None:
        from mcap.reader import make_reader

        with open(path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            stats = summary.statistics if summary else None
            if summary is None or stats is None:
                raise BagRecoveryError(f"{path}: MCAP file without summary statistics")
            schemas, channels, counts = (
                summary.schemas,
                summary.channels,
                stats.channel_message_counts,
            )
            info.start, info.end = stats.message_start_time, stats.message_end_time
            for _schema, _channel, message in reader.iter_messages():
                info.messages_compressed = message.data[:4] == b"\x28\xb5\x2f\xfd"
                break
    else:
        scan = scan or scan_mcap(path, past_damage=True)
        if scan.complete and _stopped_early(scan):
            scan.summary_bad = scan.summary_bad or scan.stop_reason
        info.scan = scan
        schemas, channels, counts = scan.schemas, scan.channels, scan.message_counts
        info.start, info.end = scan.start_time, scan.end_time
        info.messages_compressed = scan.messages_compressed
    for cid, channel in channels.items():
        schema = schemas.get(channel.schema_id)
        msgtype = schema.name if schema else ""
        type_hash = channel.metadata.get("topic_type_hash", "")
        n = int(counts.get(cid, 0))
        old = info.topics.get(channel.topic)
        info.topics[channel.topic] = (msgtype, type_hash, n + (old[2] if old else 0))
    info.count = sum(int(n) for n in counts.values())
    return info


def _stopped_early(scan: McapScan) -> bool:
    """A complete file whose walk stopped at a damaged record before its data section ended."""
    return scan.complete and scan.stop_reason.startswith("damaged record")


def damage_summary(name: str, scan: McapScan) -> str:
    """What a file's damaged chunks held and where (one line); '' when none."""
    parts = []
    for bad in scan.damaged:
        n = bad.lost_count
        held = f"{n} messages" if n is not None else "its messages"
        when = ""
        if bad.message_start_time is not None:
            t0, t1 = _stamp(bad.message_start_time), _stamp(bad.message_end_time)
            when = f" (logged {t0} to {t1} UTC)"
        parts.append(
            f"{name}: chunk at byte {bad.start} is damaged ({bad.reason}): {held}{when} "
            "cannot be read"
        )
    parts += [f"{name}: damaged {what} left out" for what in scan.skipped]
    if scan.summary_bad and not scan.damaged:
        parts.append(f"{name}: {scan.summary_bad}: summary written anew")
    if _stopped_early(scan):
        parts.append(
            f"{name}: {scan.stop_reason}: the {scan.size - scan.valid_end} bytes after it "
            "cannot be read"
        )
    return "; ".join(parts)


def describe_damage(path: str | Path) -> str:
    """The damaged chunks of a bag (directory or ``.mcap``), in one line ('' when none is
    found): for a reader whose messages failed to decompress (rosbags' ``Chunk checksum
    mismatch``)."""
    path = Path(path)
    if path.is_file():
        files = [path]
    else:
        files = _load_metadata_files(path) or bag_files(path)
    parts = []
    for f in files:
        if f.suffix == ".mcap" and f.is_file():
            scan = scan_mcap(f, past_damage=True)
            parts.append(damage_summary(f.name, scan))
    return "; ".join(p for p in parts if p)


def _stamp(ns: int) -> str:
    return datetime.fromtimestamp(ns * 1e-9, tz=UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]


def loss_summary(infos: list[FileInfo]) -> str:
    """What a cut file kept and lost, in words (one line); '' when no file was cut."""
    cut = [i for i in infos if i.scan is not None and not i.scan.complete]
    parts = [damage_summary(i.name, i.scan) for i in infos if i.scan is not None]
    parts = [p for p in parts if p]
    if not cut:
        return "; ".join(parts)
    for info in cut:
        s = info.scan
        upto = f" up to {_stamp(s.end_time)} UTC" if s.message_count else ""
        parts.append(
            f"{info.name} has no MCAP footer: kept {s.message_count} messages in "
            f"{len(s.chunks)} complete chunks{upto}; what was recorded after its last flushed "
            f"chunk is lost ({s.lost_bytes} bytes of an unfinished record dropped)"
        )
    return "; ".join(parts)


@dataclass
class RecoveryReport:
    """What :func:`recover_bag` or :func:`readable_copy` did."""

    path: Path  # the bag (or the temporary copy for readable_copy)
    files: list[FileInfo]
    repaired: list[str]  # names of files that were cut and got a summary and footer
    wrote_metadata: bool
    lost: str  # loss_summary()

    @property
    def message_count(self) -> int:
        return sum(f.count for f in self.files)


def _compression(infos: list[FileInfo], names: list[str]) -> tuple[str, str]:
    if names and all(n.endswith(".zstd") for n in names):
        return "zstd", "file"
    if any(i.messages_compressed for i in infos):
        return "zstd", "message"
    return "", ""


def _load_metadata_files(bag_dir: Path) -> list[Path] | None:
    meta = bag_dir / "metadata.yaml"
    if not meta.is_file():
        return None
    from ruamel.yaml import YAML

    try:
        info = YAML(typ="safe").load(meta.read_text())["rosbag2_bagfile_information"]
        return [bag_dir / p for p in info["relative_file_paths"]]
    except Exception as exc:
        raise BagRecoveryError(f"{meta}: unreadable ({exc})") from None


def recover_bag(path: str | Path) -> RecoveryReport:
    """Repair a bag in place: reindex every ``.mcap`` without footer (keeping all its complete
    chunks) and (re)write ``metadata.yaml`` from the files. ``path``: a bag directory or a bare
    ``.mcap`` file (repaired; no metadata written)."""
    path = Path(path)
    if not path.exists():
        raise BagRecoveryError(f"{path}: bag not found")
    if path.is_file():
        info = file_info(path, verify=True)
        repaired = []
        if info.scan is not None:
            repair_mcap(info.scan)
            repaired.append(path.name)
        return RecoveryReport(path, [info], repaired, False, loss_summary([info]))
    listed = _load_metadata_files(path)
    files = bag_files(path) if listed is None else listed
    zstd_files = bool(files) and all(p.name.endswith(".zstd") for p in files[:-1])
    infos, repaired, names = [], [], []
    with tempfile.TemporaryDirectory(prefix="bag_recover_") as tmp:
        for p in files:
            if not p.is_file():
                raise BagRecoveryError(f"{p}: listed in metadata.yaml but missing")
            plain = _decompressed(p, Path(tmp)) if p.name.endswith(".zstd") else p
            info = file_info(plain, p.name, verify=True)
            if info.scan is not None and plain is not p:  # compressed only once complete
                why = damage_summary(p.name, info.scan) or "no MCAP footer inside the .zstd"
                raise BagRecoveryError(f"{p}: damaged ({why})")
            if info.scan is not None:
                repair_mcap(info.scan)
                repaired.append(p.name)
                if zstd_files and len(files) > 1:  # file compression: keep the bag uniform
                    compress_file(p)
                    info.name = p.name + ".zstd"
            infos.append(info)
            names.append(info.name)
    if listed is not None and not repaired:
        return RecoveryReport(path, infos, [], False, "")
    fmt, mode = _compression(infos, names)
    write_metadata_yaml(path, rosbag2_metadata(infos, None, fmt, mode))
    return RecoveryReport(path, infos, repaired, True, loss_summary(infos))


def needs_recovery(path: str | Path) -> bool:
    """True for a bag directory without ``metadata.yaml`` or a ``.mcap`` without footer."""
    path = Path(path)
    if path.is_dir():
        return not (path / "metadata.yaml").is_file()
    return path.suffix == ".mcap" and path.is_file() and not has_footer(path)


def readable_copy(path: str | Path, tmp_dir: str | Path) -> RecoveryReport:
    """A readable rosbag2 directory in ``tmp_dir`` for an interrupted bag at ``path``, which is
    not modified: complete files are linked, cut ones copied up to their last complete chunk
    and reindexed, ``.zstd`` ones decompressed; ``metadata.yaml`` lists them."""
    path, tmp_dir = Path(path), Path(tmp_dir)
    files = [path] if path.is_file() else (_load_metadata_files(path) or bag_files(path))
    infos, repaired = [], []
    for p in files:
        if p.name.endswith(".zstd"):
            plain = _decompressed(p, tmp_dir)
        else:
            plain = tmp_dir / p.name
            os.symlink(p.resolve(), plain)
        try:
            info = file_info(plain, plain.name)
        except McapRecoveryError as exc:  # name the user's file, not the temporary link
            raise type(exc)(str(exc).replace(str(plain), str(p))) from None
        if info.scan is not None:
            if plain.is_symlink():  # copy the kept part of the original next to the links
                plain.unlink()
                info.scan.path = p
                repair_mcap(info.scan, plain)
            else:  # a decompressed copy of our own
                repair_mcap(info.scan)
            repaired.append(p.name)
        infos.append(info)
    fmt, mode = _compression(infos, [])
    write_metadata_yaml(tmp_dir, rosbag2_metadata(infos, None, fmt, mode))
    return RecoveryReport(tmp_dir, infos, repaired, True, loss_summary(infos))


def main(argv: list[str] | None = None) -> int:
    """Console script ``bag_recover BAG``: repair an interrupted recording in place."""
    ap = argparse.ArgumentParser(
        prog="bag_recover",
        description="Repair a rosbag2/MCAP bag whose recorder died: reindex the cut .mcap "
        "file (every complete chunk is kept) and write metadata.yaml (like `ros2 bag reindex`).",
    )
    ap.add_argument("bag", help="bag directory, or a bare .mcap file")
    args = ap.parse_args(argv)
    try:
        report = recover_bag(args.bag)
    except (McapRecoveryError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not report.repaired and not report.wrote_metadata:
        print(f"{args.bag}: complete, nothing to repair ({report.message_count} messages)")
        return 0
    if report.lost:
        print(f"{args.bag}: {report.lost}")
    what = "metadata.yaml written" if report.wrote_metadata else "file repaired"
    print(
        f"{args.bag}: {what}: {report.message_count} messages in {len(report.files)} file(s)"
        + (f", reindexed {', '.join(report.repaired)}" if report.repaired else "")
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
