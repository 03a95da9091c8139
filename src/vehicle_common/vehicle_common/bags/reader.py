"""Opening recorded bags with ``rosbags`` (rosbag2 layout, a bare ``.mcap``, ROS 1 ``.bag``).

Every reader of this project opens bags here: the replay core (:mod:`.replay`), the recorded-run
reader (:mod:`.recorded_run`) and the evaluator's odometry check. An interrupted recording is
read through a repaired copy (:mod:`.recovery`).
"""

from __future__ import annotations

import atexit
import shutil
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from ..kitti import KittiFormatError


class BagError(KittiFormatError):
    """The bag cannot be read or an option does not fit it; the message names what."""


class EmptyBagError(BagError):
    """The recording provably holds no message: its files are 0 bytes, or end after their
    header (and records that hold no message) with nothing cut short."""


#: Interrupted bags already made readable in this process: key -> (readable copy, warning).
_RECOVERED: dict[tuple, tuple[Path, str]] = {}


def _print_warning(text: str) -> None:
    print(f"warning: {text}", file=sys.stderr)


def _readable(path: Path, warn: Callable[[str], None]) -> Path:
    """A readable copy of an interrupted recording (no metadata.yaml, or a ``.mcap`` cut after
    its last flushed chunk), made once per process in a temporary folder; warns once (one line)
    saying what was lost. A recording of which nothing can be read (0 bytes, or cut before its
    first complete chunk) raises BagError instead: there is nothing to play or evaluate."""
    from .recovery import readable_copy

    files = sorted(path.iterdir()) if path.is_dir() else [path]
    key = (
        str(path.resolve()),
        tuple((f.name, f.stat().st_size, f.stat().st_mtime_ns) for f in files),
    )
    if key not in _RECOVERED:
        mcaps = [f for f in files if f.suffix == ".mcap"]
        if mcaps and all(f.stat().st_size == 0 for f in mcaps):
            what = f"{mcaps[0].name} is empty" if path.is_dir() else "empty file"
            raise EmptyBagError(
                f"{path}: {what} (0 bytes): nothing was recorded, no message to read"
            )
        tmp = Path(tempfile.mkdtemp(prefix="bag_read_"))
        atexit.register(shutil.rmtree, tmp, True)
        report = readable_copy(path, tmp)
        if report.lost and report.message_count == 0:
            dropped = sum(f.scan.lost_bytes for f in report.files if f.scan is not None)
            error = EmptyBagError if dropped == 0 else BagError
            raise error(
                f"{path}: no message can be read: the recording has no complete chunk (cut "
                f"before its first flush, or damaged; {dropped} bytes of unfinished records)"
            )
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

    from .mcap_scan import McapRecoveryError, has_footer
    from .recovery import bag_files, needs_recovery

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
    from .mcap_scan import has_footer

    return [p for p in bag_dir.glob("*.mcap") if not has_footer(p)]


def bag_messages(reader, path: str | Path, connections=None):
    """``reader.messages(connections=...)`` of an opened AnyReader; a failure while reading
    (a damaged chunk: rosbags' ``ReaderError: Chunk checksum mismatch``, a zstd error) is one
    BagError naming the bag, the damaged chunks and ``bag_recover`` (issue #42: a traceback)."""
    try:
        yield from reader.messages(connections=connections)
    except BagError:
        raise
    except Exception as exc:  # rosbags raises several unrelated types for a damaged chunk
        raise damaged_bag_error(Path(path), exc) from None


def damaged_bag_error(path: Path, exc: Exception) -> BagError:
    """One line for a bag whose messages could not be read: its damaged chunks (scanned) and
    how to keep the rest, else the reader's own words."""
    from .recovery import describe_damage

    try:
        damage = describe_damage(path)
    except Exception:  # noqa: BLE001 (the scan of a damaged bag may fail too: say what we know)
        damage = ""
    if not damage:
        words = " ".join(str(exc).split()) or type(exc).__name__
        return BagError(f"{path}: cannot read bag ({words})")
    return BagError(
        f"{path}: cannot read bag: {damage}; `bag_recover {path}` drops the damaged chunk(s) "
        "and keeps every other message"
    )
