"""Opening recorded MCAP bags (rosbag2 layout or a bare ``.mcap``) with ``rosbags``.

Shared by the bag player (kitti_player_node.bag_replay) and the evaluator (eval_node.bag_reader).
"""

from __future__ import annotations

from pathlib import Path

from .kitti import KittiFormatError


class BagError(KittiFormatError):
    """The bag cannot be read or an option does not fit it; the message names what."""


def open_reader(path: str | Path):
    """An opened ``rosbags`` AnyReader (the caller closes it) on a rosbag2 bag directory, a
    folder without ``metadata.yaml`` that holds exactly one ``.mcap``, or a bare ``.mcap`` file.
    Raises BagError naming the file when the bag is missing or unreadable."""
    from rosbags.highlevel import AnyReader

    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: bag not found")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        mcaps = sorted(path.glob("*.mcap"))
        if len(mcaps) != 1:
            raise BagError(
                f"{path}: not a rosbag2 directory (no metadata.yaml and "
                f"{len(mcaps)} .mcap files instead of one)"
            )
        path = mcaps[0]
    try:
        reader = AnyReader([path])
        reader.open()
    except Exception as exc:  # rosbags raises several unrelated types for corrupt files
        raise BagError(f"{path}: cannot read bag ({exc})") from None
    return reader
