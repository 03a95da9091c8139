"""The tracker's track table: one row per live track, its columns declared once.

:data:`COLUMNS` lists every per-track array the tracker keeps besides the motion filter's state
(which lives in the filter, row i = the table's row i). :class:`TrackTable` creates, appends,
keeps (prunes) and indexes all of them generically, so a new column is one line here.
"""

from __future__ import annotations

import numpy as np

#: name -> (dtype, shape of one row). Units and meaning:
COLUMNS: dict[str, tuple[type, tuple[int, ...]]] = {
    "ids": (np.int64, ()),  # track id (from 1, never reused)
    "hits": (np.int64, ()),  # frames matched
    "age": (np.int64, ()),  # frames since birth (birth frame = 1)
    "span": (float, ()),  # [s] time since birth (the sum of the frames' dt since)
    "misses": (np.int64, ()),  # consecutive frames unmatched
    "conf": (float, ()),  # track confidence: 1 when matched, x decay_rate per miss
    "confirmed": (bool, ()),  # matched min_hits times
    "size": (float, (3,)),  # [m] length, width, height (smoothed)
    "yaw": (float, ()),  # [rad] rotation_y (smoothed)
    "yaw_amb": (bool, ()),  # yaw known only up to 180 deg (bins or default)
    "bin": (np.int64, ()),  # last orientation bin
    "bbox": (float, (4,)),  # [px] last matched detection's 2D box
    # [px, px, m] the filtered centre's pixel (u, v) and depth when that box was matched
    "box_anchor": (float, (3,)),
    "score": (float, ()),  # last matched detection's score
    "score_sum": (float, ()),  # sum of the matched detections' scores (evidence)
    "cls": (object, ()),  # class id string
    "det_index": (np.int64, ()),  # detection matched this frame, -1 when unmatched
}


class TrackTable:
    """Per-track columns (:data:`COLUMNS`) as attributes, kept in step by :meth:`append` and
    :meth:`keep`."""

    def __init__(self):
        for name, (dtype, shape) in COLUMNS.items():
            setattr(self, name, np.zeros((0, *shape), dtype))

    def __len__(self) -> int:
        return len(self.ids)

    def append(self, **values) -> None:
        """Append rows; every column must be given (arrays of equal length)."""
        if set(values) != set(COLUMNS):
            missing = sorted(set(COLUMNS) - set(values))
            extra = sorted(set(values) - set(COLUMNS))
            raise ValueError(f"track table: missing columns {missing}, unknown {extra}")
        for name, (dtype, _) in COLUMNS.items():
            new = np.asarray(values[name], dtype=dtype)
            setattr(self, name, np.concatenate([getattr(self, name), new]))

    def keep(self, mask: np.ndarray) -> None:
        """Keep only the rows where ``mask`` is true (the others' tracks end)."""
        for name in COLUMNS:
            setattr(self, name, getattr(self, name)[mask])
