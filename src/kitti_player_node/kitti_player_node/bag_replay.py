"""Replay core (no rclpy): open an MCAP bag (rosbag2 layout or a bare ``.mcap``), read it as a
stream of (topic, type name, timestamp, raw CDR bytes) with topic selection and remapping, and
pace it.

Used by the ``bag_player`` node (:mod:`.bag_player`), which publishes the bytes as they are, and
by the evaluator, which opens recorded runs with :func:`open_reader`.
"""

from __future__ import annotations

import atexit
import importlib
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from .kitti import KittiFormatError


class BagError(KittiFormatError):
    """The bag cannot be read or an option does not fit it; the message names what."""


@dataclass(frozen=True)
class BagMessage:
    """One stored message: output topic (after remapping), type name such as
    ``std_msgs/msg/String``, receive timestamp in ns and the serialized CDR bytes."""

    topic: str
    type_name: str
    timestamp_ns: int
    data: bytes


def parse_remaps(items: Iterable[str]) -> dict[str, str]:
    """``["/old:=/new", ...]`` -> ``{"/old": "/new"}``."""
    remap = {}
    for item in items:
        old, sep, new = item.partition(":=")
        if not sep or not old or not new:
            raise BagError(f"--remap: {item!r} is not of the form /old:=/new")
        remap[old] = new
    return remap


def parse_topics(items: Iterable[str]) -> list[str] | None:
    """Comma-separated (and/or repeated) topic lists -> one list, or None for all topics."""
    topics = [t.strip() for item in items for t in item.split(",") if t.strip()]
    return topics or None


#: Interrupted bags already made readable in this process: key -> (readable copy, warning).
_RECOVERED: dict[tuple, tuple[Path, str]] = {}


def _print_warning(text: str) -> None:
    print(f"warning: {text}", file=sys.stderr)


def _readable(path: Path, warn: Callable[[str], None]) -> Path:
    """A readable copy of an interrupted recording (no metadata.yaml, or a ``.mcap`` cut after
    its last flushed chunk), made once per process in a temporary folder; warns once (one line)
    saying what was lost."""
    from .bag_recovery import readable_copy

    files = sorted(path.iterdir()) if path.is_dir() else [path]
    key = (
        str(path.resolve()),
        tuple((f.name, f.stat().st_size, f.stat().st_mtime_ns) for f in files),
    )
    if key not in _RECOVERED:
        tmp = Path(tempfile.mkdtemp(prefix="bag_read_"))
        atexit.register(shutil.rmtree, tmp, True)
        report = readable_copy(path, tmp)
        text = ""
        if report.lost:
            text = (
                f"{path}: recording was interrupted: {report.lost}. "
                f"`bag_recover {path}` repairs the bag in place"
            )
        _RECOVERED[key] = (report.path, text)
        if text:
            warn(text)
    return _RECOVERED[key][0]


def open_reader(path: str | Path, warn: Callable[[str], None] = _print_warning):
    """An opened ``rosbags`` AnyReader (the caller closes it) on a rosbag2 bag directory, a
    folder without ``metadata.yaml`` that holds one ``.mcap`` or rosbag2's split files, or a
    bare ``.mcap`` file. An interrupted recording (no ``metadata.yaml``, last file without
    footer) is read up to its last complete chunk, with one warning line through ``warn``.
    Raises BagError naming the file when the bag is missing or unreadable."""
    from rosbags.highlevel import AnyReader

    from .bag_recovery import bag_files, needs_recovery
    from .mcap_recovery import McapRecoveryError, has_footer

    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: bag not found")
    target = path
    try:
        if needs_recovery(path):
            files = bag_files(path) if path.is_dir() else [path]
            if len(files) == 1 and files[0].suffix == ".mcap" and has_footer(files[0]):
                target = files[0]  # a complete bare file in a folder
            else:
                target = _readable(path, warn)
    except (McapRecoveryError, OSError) as exc:
        raise _bag_error(path, exc) from None
    try:
        reader = AnyReader([target])
        reader.open()
    except Exception as exc:  # rosbags raises several unrelated types for corrupt files
        if target == path and path.is_dir() and _cut_files(path):
            try:  # metadata.yaml was written but a file lost its end
                return open_reader(_readable(path, warn))
            except (McapRecoveryError, OSError) as exc2:
                raise _bag_error(path, exc2) from None
        raise BagError(f"{path}: cannot read bag ({exc})") from None
    return reader


def _bag_error(path: Path, exc: Exception) -> BagError:
    """One-line BagError for a recovery failure, naming the bag once."""
    text = str(exc)
    if isinstance(exc, OSError):
        return BagError(f"{path}: cannot read bag ({text})")
    return BagError(text if text.startswith(str(path)) else f"{path}: {text}")


def _cut_files(bag_dir: Path) -> list[Path]:
    """``.mcap`` files of a bag directory that lack their footer."""
    from .mcap_recovery import has_footer

    return [p for p in bag_dir.glob("*.mcap") if not has_footer(p)]


def _check_topics(available: Iterable[str], topics: Iterable[str] | None, path) -> None:
    """Raise BagError when a requested topic is not among the bag's ``available`` topics."""
    if topics is not None:
        missing = sorted(set(topics) - set(available))
        if missing:
            raise BagError(f"--topics: {', '.join(missing)} not in bag {path}")


def bag_topics(path: str | Path) -> dict[str, str]:
    """``{topic: type name}`` of the bag's connections."""
    reader = open_reader(path)
    try:
        return {c.topic: c.msgtype for c in reader.connections}
    finally:
        reader.close()


def iter_bag(
    path: str | Path,
    topics: Iterable[str] | None = None,
    remap: dict[str, str] | None = None,
) -> Iterator[BagMessage]:
    """The bag's messages in timestamp order, restricted to ``topics`` (all when None), with
    topic names remapped. Unknown topics in ``topics`` raise BagError."""
    remap = remap or {}
    reader = open_reader(path)
    try:
        _check_topics((c.topic for c in reader.connections), topics, path)
        if topics is not None:
            conns = [c for c in reader.connections if c.topic in set(topics)]
        else:
            conns = list(reader.connections)
        if not conns:
            return
        try:
            for conn, timestamp, data in reader.messages(connections=conns):
                yield BagMessage(
                    remap.get(conn.topic, conn.topic), conn.msgtype, int(timestamp), bytes(data)
                )
        except BagError:
            raise
        except Exception as exc:
            raise BagError(f"{path}: cannot read bag ({exc})") from None
    finally:
        reader.close()


def paced(
    messages: Iterable[BagMessage],
    rate: float = 1.0,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Iterator[BagMessage]:
    """Yield ``messages`` at their recorded spacing divided by ``rate`` (``rate <= 0``: at once).

    Message i is released at ``t0 + (stamp_i - stamp_0) / rate`` wall seconds, so small delays in
    publishing do not accumulate.
    """
    t0 = first = None
    for msg in messages:
        if rate > 0:
            if t0 is None:
                t0, first = clock(), msg.timestamp_ns
            delay = t0 + (msg.timestamp_ns - first) * 1e-9 / rate - clock()
            if delay > 0:
                sleep(delay)
        yield msg


def ready_to_play(
    matched: dict[str, int], known: dict[str, int], elapsed_s: float, discovery_s: float
) -> bool:
    """Whether a replay may start without losing messages to subscribers already running.

    ``matched``: subscriptions matched per output topic; ``known``: subscriptions the ROS graph
    knows per topic (discovery can know of one before its publisher has matched it). Ready when
    every known subscription is matched and every topic has one; after ``discovery_s`` seconds
    topics nobody subscribes to no longer hold the start back (discovery of a running process
    takes up to ~2.4 s with Fast DDS on loopback, docs: ros2-from-pip notes)."""
    if any(matched.get(t, 0) < n for t, n in known.items()):
        return False
    return all(n > 0 for n in matched.values()) or elapsed_s >= discovery_s


def message_class(type_name: str):
    """The Python message class of ``pkg/msg/Name`` (or ``pkg/Name``)."""
    parts = type_name.split("/")
    if len(parts) not in (2, 3) or not all(parts):
        raise BagError(f"{type_name}: not a ROS message type name")
    try:
        return getattr(importlib.import_module(parts[0] + ".msg"), parts[-1])
    except (ImportError, AttributeError):
        raise BagError(f"{type_name}: message type not available in this installation") from None


def output_types(path: str | Path, topics: list[str] | None, remap: dict[str, str]):
    """``{output topic: type name}`` of the selected topics after remapping."""
    types = bag_topics(path)
    _check_topics(types, topics, path)
    if topics is not None:
        types = {t: types[t] for t in topics}
    out: dict[str, str] = {}
    for topic, type_name in types.items():
        new = remap.get(topic, topic)
        if out.get(new, type_name) != type_name:
            raise BagError(f"--remap: {new} would carry two types ({out[new]}, {type_name})")
        out[new] = type_name
    return out
