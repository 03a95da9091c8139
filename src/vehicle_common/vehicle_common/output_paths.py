"""Output files and folders of the command-line tools, checked before the work starts.

A tool that writes its results (``detector_offline --output``, ``tracker_offline --output``,
``evaluate --json/--report``, ``kitti_synth --output``, ``detector_train --output``, the demo's
``--output``) creates or checks the place first, so that an unwritable path is one line naming
it and exit code 2 at once, not a traceback after minutes of work. :class:`OutputPathError` is a
:class:`~vehicle_common.kitti.KittiFormatError`, which every tool's ``main`` already prints as
``error: <message>``; :func:`os_error_line` words an OSError met later (a full disk) the same way.
"""

from __future__ import annotations

import os
from pathlib import Path

from .kitti import KittiFormatError


class OutputPathError(KittiFormatError):
    """An output file or folder cannot be created or written; the message names it."""


def os_error_line(exc: OSError) -> str:
    """``<file>: <reason>`` of an OSError (one line)."""
    name = exc.filename if exc.filename is not None else ""
    reason = exc.strerror or str(exc)
    return f"{name}: {reason}" if name else reason


def make_output_dir(path: str | os.PathLike, what: str = "output folder") -> Path:
    """Create the folder ``path`` (and its parents) if needed and check that files can be
    written in it; raises OutputPathError naming it and ``what`` it is for."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputPathError(f"{path}: exists and is not a folder (needed as {what})")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(f"{path}: cannot create {what} ({exc.strerror or exc})") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise OutputPathError(f"{path}: cannot write in {what} (permission denied)")
    return path


def check_output_file(path: str | os.PathLike, what: str = "output file") -> Path:
    """Check that the file ``path`` can be written (its folder is created if needed; an
    existing file is replaced later); raises OutputPathError naming it."""
    path = Path(path)
    if path.is_dir():
        raise OutputPathError(f"{path}: cannot write {what}: it is a folder")
    try:
        make_output_dir(path.parent, "the file's folder")
    except OutputPathError as exc:
        raise OutputPathError(f"{path}: cannot write {what}: {exc}") from None
    if path.exists() and not os.access(path, os.W_OK):
        raise OutputPathError(f"{path}: cannot write {what} (permission denied)")
    return path
