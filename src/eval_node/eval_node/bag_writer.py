"""Writing rosbag2-layout bags with MCAP storage from serialized (CDR) messages.

The pure core of the ``bag_recorder`` node (no rclpy): :class:`BagWriter` takes raw CDR bytes
with a topic, a ROS type name (``pkg/msg/Type``) and a receive time, and writes them with
``rosbags.rosbag2.Writer`` (version 9, MCAP). Message definitions and RIHS01 hashes are embedded
for every type, custom ones included (types are loaded from the ``share/<pkg>/msg/*.msg`` files
of the environment), so rosbags, rosbag2 and Foxglove can read the bag without the package.

Optional zstd compression (``storage``: MCAP chunk compression, readable by every MCAP tool;
``message``: each message; ``file``: the whole file after closing) and size-based splitting
(``max_bag_size`` bytes per ``.mcap`` file; ``metadata.yaml`` lists every file). All public
methods are thread-safe (one lock).
"""

from __future__ import annotations

import shutil
import threading
from collections import Counter
from io import StringIO
from pathlib import Path

from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from ruamel.yaml import YAML

COMPRESSION_MODES = {
    "storage": CompressionMode.STORAGE,
    "message": CompressionMode.MESSAGE,
    "file": CompressionMode.FILE,
}


class BagWriterError(RuntimeError):
    """A bag cannot be written (existing output, unknown message type...)."""


def _share_dirs() -> list[Path]:
    """Install prefixes' share folders (AMENT_PREFIX_PATH, then the interpreter's prefix)."""
    import os
    import sys

    dirs = []
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            dirs.append(Path(prefix) / "share")
    dirs.append(Path(sys.prefix) / "share")
    return [d for d in dirs if d.is_dir()]


class MessageDefinitions:
    """Message definitions (msgdef text) and RIHS01 hashes of ROS 2 types.

    Starts from rosbags' Jazzy typestore and registers, on demand, a package's ``.msg`` files
    found under ``share/<pkg>/msg`` (for the project's ``stereo_vehicle_msgs``).
    """

    def __init__(self) -> None:
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        self._loaded_pkgs: set[str] = set()

    def _load_package(self, pkg: str) -> None:
        if pkg in self._loaded_pkgs:
            return
        self._loaded_pkgs.add(pkg)
        for share in _share_dirs():
            msg_dir = share / pkg / "msg"
            if not msg_dir.is_dir():
                continue
            types = {}
            for f in sorted(msg_dir.glob("*.msg")):
                types.update(get_types_from_msg(f.read_text(), f"{pkg}/msg/{f.stem}"))
            self.typestore.register(types)
            return

    def get(self, msgtype: str) -> tuple[str, str]:
        """(msgdef, rihs01) of ``msgtype`` (``pkg/msg/Type``); raises BagWriterError if unknown."""
        if msgtype not in self.typestore.types:
            self._load_package(msgtype.split("/")[0])
        if msgtype not in self.typestore.types:
            raise BagWriterError(f"{msgtype}: unknown message type (no .msg definition found)")
        # Dependencies of a custom type may live in another package.
        try:
            msgdef, _ = self.typestore.generate_msgdef(msgtype, ros_version=2)
        except KeyError as exc:
            self._load_package(str(exc.args[0]).split("/")[0])
            msgdef, _ = self.typestore.generate_msgdef(msgtype, ros_version=2)
        return msgdef, self.typestore.hash_rihs01(msgtype)


class BagWriter:
    """A rosbag2 (v9, MCAP) bag being written from serialized messages.

    ``compression``: ``"none"`` or ``"zstd"``; ``compression_mode``: ``storage`` (MCAP chunk
    compression, default), ``message`` or ``file``. ``max_bag_size``: bytes of message data per
    ``.mcap`` file before a new one is started (0: one file). Timestamps must be in ns; they are
    made non-decreasing so that the file keeps the order in which messages were written.
    """

    def __init__(
        self,
        path: str | Path,
        compression: str = "none",
        compression_mode: str = "storage",
        max_bag_size: int = 0,
        definitions: MessageDefinitions | None = None,
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
        if self.path.exists():
            raise BagWriterError(f"{self.path}: exists already, not overwriting")
        self.compression = compression
        self.compression_mode = compression_mode
        self.max_bag_size = int(max_bag_size)
        self.defs = definitions or MessageDefinitions()
        self.counts: Counter[str] = Counter()
        self.types: dict[str, str] = {}
        self._lock = threading.Lock()
        self._writer: Writer | None = None
        self._conns: dict[str, object] = {}
        self._split_bytes = 0
        self._splits: list[dict] = []  # closed files: {"path", "start", "end", "count"}
        self._split_counts: Counter[str] = Counter()
        self._split_range = [None, None]
        self._last_ts = 0
        self._closed = False
        self.path.mkdir(parents=True)
        self._open_split()

    # ------------------------------------------------------------------ split files
    def _split_tmp(self) -> Path:
        return self.path / f".split_{len(self._splits)}"

    def _open_split(self) -> None:
        w = Writer(self._split_tmp(), version=9, storage_plugin=StoragePlugin.MCAP)
        if self.compression == "zstd":
            w.set_compression(COMPRESSION_MODES[self.compression_mode], CompressionFormat.ZSTD)
        w.open()
        self._writer = w
        self._conns = {}
        self._split_bytes = 0
        self._split_counts = Counter()
        self._split_range = [None, None]
        for topic, msgtype in self.types.items():
            self._add_connection(topic, msgtype)

    def _close_split(self) -> None:
        w, self._writer = self._writer, None
        assert w is not None
        w.close()
        tmp = self._split_tmp()
        produced = [p for p in tmp.iterdir() if ".mcap" in p.name]
        name = f"{self.path.name}_{len(self._splits)}.mcap"
        for p in produced:
            dst = self.path / (name + p.name.split(".mcap", 1)[1])
            p.replace(dst)
            self._splits.append(
                {
                    "path": dst.name,
                    "start": self._split_range[0] or 0,
                    "end": self._split_range[1] or 0,
                    "count": sum(self._split_counts.values()),
                }
            )
        shutil.rmtree(tmp, ignore_errors=True)

    def _add_connection(self, topic: str, msgtype: str) -> None:
        msgdef, rihs01 = self.defs.get(msgtype)
        self._conns[topic] = self._writer.add_connection(
            topic, msgtype, msgdef=msgdef, rihs01=rihs01
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
            self._add_connection(topic, msgtype)  # raises before registering an unknown type
            self.types[topic] = msgtype

    def write(self, topic: str, data: bytes, timestamp_ns: int) -> None:
        """Write one serialized message (CDR bytes) received at ``timestamp_ns``."""
        with self._lock:
            if self._closed:
                raise BagWriterError(f"{self.path}: bag is closed")
            if topic not in self._conns:
                raise BagWriterError(f"{topic}: topic not added")
            if self.max_bag_size and self._split_bytes >= self.max_bag_size:
                self._close_split()
                self._open_split()
            ts = max(int(timestamp_ns), self._last_ts)
            self._last_ts = ts
            self._writer.write(self._conns[topic], ts, bytes(data))
            self._split_bytes += len(data) + 40
            self.counts[topic] += 1
            self._split_counts[topic] += 1
            if self._split_range[0] is None:
                self._split_range[0] = ts
            self._split_range[1] = ts

    def flush(self) -> None:
        """Push buffered messages to the file (closes the pending MCAP chunk)."""
        with self._lock:
            storage = getattr(self._writer, "storage", None) if self._writer else None
            chunk = getattr(storage, "chunk", None)
            if chunk is not None and chunk.bio.tell() and sum(self._split_counts.values()):
                storage.close_chunk()
                storage.bio.flush()

    @property
    def files(self) -> list[str]:
        """Names of the finished ``.mcap`` files (all of them after :meth:`close`)."""
        return [s["path"] for s in self._splits]

    def close(self) -> dict[str, int]:
        """Finish the file(s), write ``metadata.yaml``; returns the message count per topic."""
        with self._lock:
            if self._closed:
                return dict(self.counts)
            self._closed = True
            self._close_split()
            self._write_metadata()
            return dict(self.counts)

    def _write_metadata(self) -> None:
        starts = [s["start"] for s in self._splits if s["count"]]
        ends = [s["end"] for s in self._splits if s["count"]]
        start = min(starts) if starts else 0
        duration = (max(ends) - start) if ends else 0
        compressed = self.compression == "zstd" and self.compression_mode != "storage"
        info = {
            "version": 9,
            "storage_identifier": "mcap",
            "relative_file_paths": [s["path"] for s in self._splits],
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": sum(self.counts.values()),
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": topic,
                        "type": msgtype,
                        "serialization_format": "cdr",
                        "offered_qos_profiles": [],
                        "type_description_hash": self.defs.get(msgtype)[1],
                    },
                    "message_count": self.counts[topic],
                }
                for topic, msgtype in self.types.items()
            ],
            "compression_format": "zstd" if compressed else "",
            "compression_mode": self.compression_mode if compressed else "",
            "files": [
                {
                    "path": s["path"],
                    "starting_time": {"nanoseconds_since_epoch": s["start"]},
                    "duration": {"nanoseconds": s["end"] - s["start"]},
                    "message_count": s["count"],
                }
                for s in self._splits
            ],
            "custom_data": None,
            "ros_distro": "jazzy",
        }
        yaml = YAML(typ="safe")
        yaml.default_flow_style = False
        out = StringIO()
        yaml.dump({"rosbag2_bagfile_information": info}, out)
        tmp = self.path / "metadata.yaml.tmp"
        tmp.write_text(out.getvalue())
        tmp.replace(self.path / "metadata.yaml")


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
