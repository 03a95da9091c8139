"""Writing rosbag2-layout bags with MCAP storage from serialized (CDR) messages.

The pure core of the ``bag_recorder`` node (no rclpy): :class:`BagWriter` takes raw CDR bytes
with a topic, a ROS type name (``pkg/msg/Type``) and a receive time, and writes them with
mcap's ``Writer`` in rosbag2's layout (version 9: ``<bag>/<bag>_<i>.mcap`` + ``metadata.yaml``,
the ``ros2`` profile, ``ros2msg`` schemas, ``cdr`` messages). Message definitions and RIHS01
hashes are embedded for every type, custom ones included (types are loaded from the
``share/<pkg>/msg/*.msg`` files of the environment), so rosbags, rosbag2 and Foxglove can read
the bag without the package.

Optional zstd compression (``storage``: MCAP chunk compression, readable by every MCAP tool;
``message``: each message; ``file``: the whole file after closing) and size-based splitting
(``max_bag_size`` bytes per ``.mcap`` file; ``metadata.yaml`` lists every file). All public
methods are thread-safe (one lock). The pending chunk is written out to the file as soon as it
holds ``flush_messages`` messages or its first one is ``flush_period`` old (checked at each
write), and :meth:`BagWriter.flush` (a thread calls it every ``flush_period``) also fsyncs it,
so a killed recorder loses at most the last chunk (see :mod:`.recovery`).
"""

from __future__ import annotations

import os
import threading
import time
from collections import Counter
from pathlib import Path

import zstandard
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from ..message_definitions import MessageDefinitions
from .metadata import (
    ROS_DISTRO,
    FileInfo,
    compress_file,
    dump_yaml,
    rosbag2_metadata,
    write_metadata_yaml,
)

COMPRESSION_MODES = ("storage", "message", "file")
#: Bytes of messages per MCAP chunk before it is closed (rosbag2's and rosbags' 1 MiB).
CHUNK_SIZE = 1 << 20
#: Messages per MCAP chunk before it is written out (the recorder's default ``flush_messages``):
#: the graph records 10 messages a frame (about 26 KB without images), so a killed recorder
#: loses at most 2 frames, or ``flush_period``, whichever is less. A chunk written only by the
#: once-a-second flush thread left a bag killed 1 s into real 0005 with no frame in 1 of 7 runs
#: under load; a chunk's own overhead (its header and per-topic message index, ~0.5 KB) is ~1 %
#: of 20 messages.
FLUSH_MESSAGES = 20
LIBRARY = "stereo_vehicle_tracking bag_writer (mcap python)"


class BagWriterError(RuntimeError):
    """A bag cannot be written (existing output, unknown message type...)."""


def empty_bag_files(path: Path) -> list[Path] | None:
    """The files of ``path`` when it is a bag folder that holds no message, as a recorder
    leaves it when the graph's start failed (only its own ``<name>_<i>.mcap`` files and
    ``metadata.yaml``; an empty folder too), else None: anything else, or a file that cannot
    be read, counts as recorded data."""
    import re

    from .reader import BagError, EmptyBagError, open_reader

    if not path.is_dir() or path.is_symlink():
        return None
    files = sorted(path.iterdir())
    own = re.compile(rf"{re.escape(path.name)}_\d+\.mcap")
    mcaps = [f for f in files if own.fullmatch(f.name) and f.is_file() and not f.is_symlink()]
    if len(mcaps) + (path / "metadata.yaml").is_file() != len(files):
        return None
    if not mcaps:
        return [] if not files else None  # an empty folder, or metadata.yaml alone
    try:
        reader = open_reader(path, warn=lambda _text: None)
    except EmptyBagError:
        return files  # a header without a message, nothing cut short: no data to lose
    except BagError:
        return None
    try:
        return files if sum(c.msgcount for c in reader.connections) == 0 else None
    finally:
        reader.close()


class BagWriter:
    """A rosbag2 (v9, MCAP) bag being written from serialized messages.

    ``compression``: ``"none"`` or ``"zstd"``; ``compression_mode``: ``storage`` (MCAP chunk
    compression, default), ``message`` or ``file``. ``max_bag_size``: bytes of message data per
    ``.mcap`` file before a new one is started (0: one file). ``flush_period`` > 0: a thread
    calls :meth:`flush` this often [s], and a write closes and writes out the pending chunk once
    its first message is that old; ``flush_messages`` > 0: also once it holds that many.
    Timestamps must be in ns; they are made non-decreasing so that the file keeps the order in
    which messages were written.

    Crash safety: each file is written under its final name ``<bag>_<i>.mcap`` from the start;
    :meth:`flush` closes the pending chunk and fsyncs it, so a writer killed at any moment leaves
    a file whose complete chunks ``bag_recover`` (or any reader of this project) recovers.
    """

    def __init__(
        self,
        path: str | Path,
        compression: str = "none",
        compression_mode: str = "storage",
        max_bag_size: int = 0,
        definitions: MessageDefinitions | None = None,
        chunk_size: int = CHUNK_SIZE,
        flush_period: float = 0.0,
        flush_messages: int = 0,
    ) -> None:
        self.path = Path(path)
        if compression not in ("none", "zstd"):
            raise BagWriterError(f"compression: {compression!r} is not 'none' or 'zstd'")
        if compression == "zstd" and compression_mode not in COMPRESSION_MODES:
            raise BagWriterError(
                f"compression_mode: {compression_mode!r} is not one of {sorted(COMPRESSION_MODES)}"
            )
        if max_bag_size < 0:
            raise BagWriterError(f"max_bag_size: {max_bag_size} < 0")
        if not flush_period >= 0:  # (NaN too)
            raise BagWriterError(f"flush_period: {flush_period} is not >= 0")
        if flush_messages < 0:
            raise BagWriterError(f"flush_messages: {flush_messages} < 0")
        #: an existing bag at ``path`` without a single message (left by a start that failed)
        #: was replaced; a bag that holds messages is never touched
        self.replaced_empty = False
        if self.path.exists():
            empty = empty_bag_files(self.path)
            if empty is None:
                raise BagWriterError(
                    f"{self.path}: exists already and is not an empty bag, not overwriting"
                )
            for f in empty:
                f.unlink()
            self.path.rmdir()
            self.replaced_empty = True
        self.compression = compression
        self.compression_mode = compression_mode if compression == "zstd" else ""
        self.max_bag_size = int(max_bag_size)
        self.chunk_size = int(chunk_size)
        self.defs = definitions or MessageDefinitions(BagWriterError)
        self.counts: Counter[str] = Counter()
        self.types: dict[str, str] = {}
        self._lock = threading.Lock()
        self._file = None
        self._writer: McapWriter | None = None
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._split_bytes = 0
        self._splits: list[FileInfo] = []  # closed files
        self._split_counts: Counter[str] = Counter()
        self._split_range: list[int | None] = [None, None]
        self._dirty = False  # messages in the pending chunk, not yet written out
        self._unsynced = False  # chunks written out, not yet fsynced
        self._pending = 0  # messages in the pending chunk
        self._pending_since = 0.0  # time.monotonic() of its first message
        self.flush_period = float(flush_period)
        self.flush_messages = int(flush_messages)
        self._stop_flush = threading.Event()
        #: the OSError that stopped the flush thread (a full disk), for the owner to report
        self.error: OSError | None = None
        self._flush_thread: threading.Thread | None = None
        self._last_ts = 0
        self._closed = False
        self.path.mkdir(parents=True)
        self._open_split()
        if flush_period > 0:
            self._start_autoflush(float(flush_period))

    # ------------------------------------------------------------------ split files
    def _split_name(self) -> str:
        return f"{self.path.name}_{len(self._splits)}.mcap"

    def _open_split(self) -> None:
        # open across calls until the split is closed (a context manager cannot span them)
        self._file = open(self.path / self._split_name(), "xb")  # noqa: SIM115
        storage_zstd = self.compression_mode == "storage"
        self._writer = McapWriter(
            self._file,
            chunk_size=self.chunk_size,
            compression=CompressionType.ZSTD if storage_zstd else CompressionType.NONE,
        )
        self._writer.start(profile="ros2", library=LIBRARY)
        self._schemas, self._channels = {}, {}
        self._split_bytes = 0
        self._split_counts = Counter()
        self._split_range = [None, None]
        for topic, msgtype in self.types.items():
            self._add_channel(topic, msgtype)
        self._sync()  # the header is on disk: even an empty file is a recoverable MCAP

    def _sync(self) -> None:
        self._writer.flush()  # closes the pending chunk (if it holds messages), writes it out
        os.fsync(self._file.fileno())
        self._dirty = self._unsynced = False
        self._pending = 0

    def _write_out(self) -> None:
        """Close the pending chunk and write it to the file (no fsync: the flush thread does
        that; a killed process loses nothing the OS has)."""
        self._writer.flush()
        self._dirty, self._unsynced = False, True
        self._pending = 0

    def _split_info(self, name: str) -> FileInfo:
        start, end = (t or 0 for t in self._split_range)
        topics = {t: (m, self.defs.get(m)[1], self._split_counts[t]) for t, m in self.types.items()}
        return FileInfo(name, start, end, sum(self._split_counts.values()), topics)

    def _close_split(self) -> None:
        name = self._split_name()
        info = self._split_info(name)
        # rosbag2 embeds the bag's metadata (for this file) in each file
        meta = rosbag2_metadata([info], list(self.types), *self._metadata_compression())
        self._writer.add_metadata(
            "rosbag2",
            {"serialized_metadata": dump_yaml(meta).strip(), "ros_distro": ROS_DISTRO},
        )
        self._writer.finish()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        self._writer = self._file = None
        if self.compression_mode == "file":
            info.name = compress_file(self.path / name).name
        self._splits.append(info)

    def _metadata_compression(self) -> tuple[str, str]:
        """metadata.yaml's (compression_format, compression_mode): chunk compression is MCAP's
        own and invisible to rosbag2, the per-message and per-file kinds are not."""
        if self.compression_mode in ("message", "file"):
            return "zstd", self.compression_mode
        return "", ""

    def _add_channel(self, topic: str, msgtype: str) -> None:
        msgdef, rihs01 = self.defs.get(msgtype)
        if msgtype not in self._schemas:
            self._schemas[msgtype] = self._writer.register_schema(
                msgtype, "ros2msg", msgdef.encode()
            )
        self._channels[topic] = self._writer.register_channel(
            topic,
            "cdr",
            self._schemas[msgtype],
            {"offered_qos_profiles": "[]", "topic_type_hash": rihs01},
        )

    # ------------------------------------------------------------------ public API
    def add_topic(self, topic: str, msgtype: str) -> None:
        """Declare a topic and its type (``pkg/msg/Type``) before writing to it."""
        with self._lock:
            if self._closed:
                raise BagWriterError(f"{self.path}: bag is closed")
            if topic in self.types:
                if self.types[topic] != msgtype:
                    raise BagWriterError(
                        f"{topic}: type {msgtype} differs from the recorded {self.types[topic]}"
                    )
                return
            self.defs.get(msgtype)  # raises before registering an unknown type
            self._add_channel(topic, msgtype)
            self.types[topic] = msgtype

    def write(self, topic: str, data: bytes, timestamp_ns: int) -> None:
        """Write one serialized message (CDR bytes) received at ``timestamp_ns``."""
        with self._lock:
            if self._closed:
                raise BagWriterError(f"{self.path}: bag is closed")
            if topic not in self._channels:
                raise BagWriterError(f"{topic}: topic not added")
            if self.max_bag_size and self._split_bytes >= self.max_bag_size:
                self._close_split()
                self._open_split()
            ts = max(int(timestamp_ns), self._last_ts)
            self._last_ts = ts
            data = bytes(data)
            if self.compression_mode == "message":
                data = zstandard.compress(data)
            self._writer.add_message(
                self._channels[topic],
                log_time=ts,
                data=data,
                publish_time=ts,
                sequence=self.counts[topic] & 0xFFFFFFFF,
            )
            now = time.monotonic()
            if not self._pending:
                self._pending_since = now
            self._pending += 1
            self._dirty = True
            if (self.flush_messages and self._pending >= self.flush_messages) or (
                self.flush_period and now - self._pending_since >= self.flush_period
            ):
                self._write_out()
            self._split_bytes += len(data) + 40
            self.counts[topic] += 1
            self._split_counts[topic] += 1
            if self._split_range[0] is None:
                self._split_range[0] = ts
            self._split_range[1] = ts

    def flush(self) -> None:
        """Write the pending MCAP chunk to disk (file flush + fsync): after this, a crash loses
        none of the messages written so far. The fsync runs outside the lock (on a duplicate of
        the file descriptor), so writers are held up only while the chunk is written out."""
        with self._lock:
            if self._writer is None or not (self._dirty or self._unsynced):
                return
            if self._dirty:
                self._write_out()  # closes the pending chunk, writes it to the OS
            self._unsynced = False
            fd = os.dup(self._file.fileno())
        try:
            os.fsync(fd)
        finally:
            os.close(fd)

    def _start_autoflush(self, period_s: float) -> None:
        """Call :meth:`flush` every ``period_s`` seconds from a daemon thread until
        :meth:`close` (a slow fsync then never stalls the thread that receives messages)."""

        def run() -> None:
            while not self._stop_flush.wait(period_s):
                try:
                    self.flush()
                except OSError as exc:  # a full disk: kept for the recorder to report
                    self.error = exc
                    return

        self._flush_thread = threading.Thread(target=run, name="bag_flush", daemon=True)
        self._flush_thread.start()

    @property
    def files(self) -> list[str]:
        """Names of the finished ``.mcap`` files (all of them after :meth:`close`)."""
        return [s.name for s in self._splits]

    def close(self) -> dict[str, int]:
        """Finish the file(s), write ``metadata.yaml``; returns the message count per topic."""
        self._stop_flush.set()
        if self._flush_thread is not None:
            self._flush_thread.join()
        with self._lock:
            if self._closed:
                return dict(self.counts)
            self._closed = True
            self._close_split()
            info = rosbag2_metadata(self._splits, list(self.types), *self._metadata_compression())
            write_metadata_yaml(self.path, info)
            return dict(self.counts)


def ros_type_name(msg) -> str:
    """``pkg/msg/Type`` of an rclpy message instance."""
    return f"{type(msg).__module__.split('.')[0]}/msg/{type(msg).__name__}"


def write_bag(path: str | Path, messages, **options) -> dict[str, int]:
    """Write ``(topic, rclpy message, receive time ns)`` items to a new bag (for tools and
    tests; needs rclpy for serialisation). ``options`` go to :class:`BagWriter`."""
    from rclpy.serialization import serialize_message

    writer = BagWriter(path, **options)
    try:
        for topic, msg, t_ns in messages:
            writer.add_topic(topic, ros_type_name(msg))
            writer.write(topic, serialize_message(msg), t_ns)
    finally:
        counts = writer.close()
    return counts
