"""rosbag2's ``metadata.yaml`` (version 9) and its per-file compression, for bags of MCAP files.

Written by :class:`.writer.BagWriter` when it closes a bag, and by :mod:`.recovery` from what
the files of an interrupted or damaged bag hold. Pure core, no rclpy.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from io import StringIO
from pathlib import Path

from .mcap_scan import McapScan

ROS_DISTRO = "jazzy"


@dataclass
class FileInfo:
    """What one ``.mcap`` file of a bag holds (for ``metadata.yaml``)."""

    name: str  # file name inside the bag directory
    start: int = 0  # first message time [ns]
    end: int = 0  # last message time [ns]
    count: int = 0
    topics: dict[str, tuple[str, str, int]] = field(default_factory=dict)  # type, hash, count
    messages_compressed: bool = False
    scan: McapScan | None = None  # set for a file that was cut (no footer)


def topic_entry(topic: str, msgtype: str, type_hash: str, count: int) -> dict:
    """One ``topics_with_message_count`` entry of rosbag2's metadata (version 9)."""
    return {
        "topic_metadata": {
            "name": topic,
            "type": msgtype,
            "serialization_format": "cdr",
            "offered_qos_profiles": [],
            "type_description_hash": type_hash,
        },
        "message_count": count,
    }


def rosbag2_metadata(
    files: list[FileInfo],
    topic_order: list[str] | None = None,
    compression_format: str = "",
    compression_mode: str = "",
) -> dict:
    """rosbag2's ``rosbag2_bagfile_information`` (version 9) for ``files`` (in order)."""
    topics: dict[str, list] = {}
    for f in files:
        for topic, (msgtype, type_hash, count) in f.topics.items():
            entry = topics.setdefault(topic, [msgtype, type_hash, 0])
            entry[1] = entry[1] or type_hash
            entry[2] += count
    order = [t for t in (topic_order or []) if t in topics]
    order += [t for t in topics if t not in order]
    counted = [f for f in files if f.count]
    start = min((f.start for f in counted), default=0)
    end = max((f.end for f in counted), default=0)
    return {
        "version": 9,
        "storage_identifier": "mcap",
        "relative_file_paths": [f.name for f in files],
        "duration": {"nanoseconds": end - start},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": sum(f.count for f in files),
        "topics_with_message_count": [topic_entry(t, *topics[t]) for t in order],
        "compression_format": compression_format,
        "compression_mode": compression_mode,
        "files": [
            {
                "path": f.name,
                "starting_time": {"nanoseconds_since_epoch": f.start},
                "duration": {"nanoseconds": f.end - f.start},
                "message_count": f.count,
            }
            for f in files
        ],
        "custom_data": None,
        "ros_distro": ROS_DISTRO,
    }


def dump_yaml(data: dict) -> str:
    from ruamel.yaml import YAML

    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    out = StringIO()
    yaml.dump(data, out)
    return out.getvalue()


def write_metadata_yaml(bag_dir: str | Path, info: dict) -> Path:
    """Write ``metadata.yaml`` atomically (temporary file, fsync, rename)."""
    bag_dir = Path(bag_dir)
    tmp = bag_dir / "metadata.yaml.tmp"
    with open(tmp, "w") as f:
        f.write(dump_yaml({"rosbag2_bagfile_information": info}))
        f.flush()
        os.fsync(f.fileno())
    dst = bag_dir / "metadata.yaml"
    tmp.replace(dst)
    return dst


def compress_file(path: Path) -> Path:
    """rosbag2's file compression: ``x.mcap`` -> ``x.mcap.zstd`` (written aside, fsynced,
    renamed, then the original removed, so a crash leaves one complete copy)."""
    import zstandard

    dst = path.with_name(path.name + ".zstd")
    tmp = dst.with_name(dst.name + ".tmp")
    with open(path, "rb") as fin, open(tmp, "wb") as fout:
        zstandard.ZstdCompressor().copy_stream(fin, fout)
        fout.flush()
        os.fsync(fout.fileno())
    tmp.replace(dst)
    path.unlink()
    return dst
