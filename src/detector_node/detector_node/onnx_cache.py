"""A user cache of what the detector derives from a checkpoint: its configuration and
orientation head (``meta``) and the ONNX graph of its dense part per input size (``onnx``).
Pure: no torch (reading the cache is what lets the node start without PyTorch).

Where: ``$VEHICLE_DETECTOR_CACHE`` when set (``off`` disables the cache), else
``$XDG_CACHE_HOME/stereo_vehicle_tracking/detector``, else
``~/.cache/stereo_vehicle_tracking/detector``.

Keys: the checkpoint's CONTENT (sha256 of the file, so retrained weights under the same name
are a new entry), the code that writes the entries (sha256 of the modules that define the
graph and its conversion, so a changed exporter never reads an old graph), the input size.
Each entry is ONE ``.npz`` file holding a sha256 of its own arrays: it is written to a
temporary file in the cache folder and renamed into place (``os.replace``: concurrent writers
each write a complete file, the last rename wins, readers never see a partial file); a file
that does not load or whose checksum differs (a corrupt disk, a hand-edited file) is removed
and rebuilt. Entries not used for long are pruned beyond :data:`MAX_ENTRIES`. A cache folder
that cannot be written is reported once (:attr:`OnnxCache.problems`) and the detector works
without it (the graph is then rebuilt at each start).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

CACHE_ENV = "VEHICLE_DETECTOR_CACHE"
APP_FOLDER = "stereo_vehicle_tracking"
#: the entries' layout (bumped when it changes)
FORMAT = 1
#: entries kept (the most recently used); an ONNX graph of the shipped CenterNet is 8 MB
MAX_ENTRIES = 16
#: a temporary file older than this was left by a writer that died [s]
STALE_TMP_S = 3600.0
#: the modules whose code decides what an entry holds
_EXPORTER_MODULES = ("onnx_backend.py", "tfjs_graph.py", "centernet.py", "checkpoint.py")
_CHECKSUM = "__sha256__"


def cache_dir(environ: dict | None = None) -> Path | None:
    """The cache folder (see the module docstring); None when disabled."""
    env = os.environ if environ is None else environ
    given = env.get(CACHE_ENV)
    if given is not None:
        return None if given.strip().lower() in ("", "off", "0", "none") else Path(given)
    base = env.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / APP_FOLDER / "detector"


def file_digest(path: str | os.PathLike) -> str:
    """sha256 of a file's content (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def exporter_digest() -> str:
    """sha256 (hex) of the entry format and of the modules that write the entries."""
    h = hashlib.sha256(f"format {FORMAT}".encode())
    here = Path(__file__).resolve().parent
    for name in _EXPORTER_MODULES:
        h.update(name.encode())
        h.update((here / name).read_bytes())
    return h.hexdigest()


def _checksum(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for key in sorted(arrays):
        a = np.ascontiguousarray(arrays[key])
        h.update(f"{key}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def text_array(text: str) -> np.ndarray:
    """A string as a uint8 array (entries hold arrays only: loaded without pickle)."""
    return np.frombuffer(text.encode(), np.uint8)


def array_text(a: np.ndarray) -> str:
    return bytes(np.asarray(a, np.uint8)).decode()


def json_array(value) -> np.ndarray:
    return text_array(json.dumps(value, sort_keys=True))


def array_json(a: np.ndarray):
    return json.loads(array_text(a))


class OnnxCache:
    """The entries of one cache folder (``folder`` None: no cache, every read misses and
    writes are dropped)."""

    def __init__(self, folder: str | os.PathLike | None) -> None:
        self.folder = Path(folder) if folder is not None else None
        #: what went wrong (unwritable folder, corrupt entries), one line each, for the log
        self.problems: list[str] = []
        self._exporter: str | None = None

    def key(self, checkpoint_digest: str, *parts) -> str:
        """An entry name from the checkpoint's digest, the exporter's and ``parts``."""
        if self._exporter is None:
            self._exporter = exporter_digest()
        tail = "-".join(str(p) for p in parts)
        return f"{checkpoint_digest[:20]}-{self._exporter[:12]}" + (f"-{tail}" if tail else "")

    def _path(self, name: str) -> Path:
        return self.folder / f"{name}.npz"

    def read(self, name: str) -> dict[str, np.ndarray] | None:
        """The arrays of entry ``name``, or None (missing, unreadable or corrupt: removed)."""
        if self.folder is None:
            return None
        path = self._path(name)
        if not path.is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
            stored = array_text(arrays.pop(_CHECKSUM))
            if stored != _checksum(arrays):
                raise ValueError("checksum mismatch")
        except Exception as exc:  # a damaged zip raises many types
            self.problems.append(f"{path}: corrupt cache entry ({exc}); rebuilt")
            with contextlib.suppress(OSError):
                path.unlink()
            return None
        with contextlib.suppress(OSError):
            os.utime(path)  # most recently used (pruning)
        return arrays

    def write(self, name: str, arrays: dict[str, np.ndarray]) -> bool:
        """Store entry ``name`` atomically; False (and a problem noted) when it cannot be."""
        if self.folder is None:
            return False
        payload = {k: np.ascontiguousarray(v) for k, v in arrays.items()}
        payload[_CHECKSUM] = text_array(_checksum(payload))
        tmp = None
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".tmp", dir=self.folder)
            with os.fdopen(fd, "wb") as f:
                np.savez(f, **payload)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self._path(name))
            tmp = None
        except OSError as exc:
            self.problems.append(f"{self.folder}: cannot write the detector cache ({exc})")
            return False
        finally:
            if tmp is not None:
                with contextlib.suppress(OSError):
                    os.unlink(tmp)
        self._prune()
        return True

    def _prune(self) -> None:
        """Keep the :data:`MAX_ENTRIES` most recently used entries; remove stale temporary
        files of writers that died."""
        try:
            entries = sorted(
                self.folder.glob("*.npz"), key=lambda p: p.stat().st_mtime, reverse=True
            )
            for path in entries[MAX_ENTRIES:]:
                path.unlink()
            now = time.time()
            for path in self.folder.glob(".*.tmp"):
                if now - path.stat().st_mtime > STALE_TMP_S:
                    path.unlink()
        except OSError:  # another process pruned it first
            pass
