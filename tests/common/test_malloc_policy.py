"""keep_freed_memory: a node process keeps freed blocks for reuse (glibc mallopt)."""

from __future__ import annotations

import platform
import subprocess
import sys
import textwrap

import pytest

GLIBC = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"

CHILD = """
    import ctypes, sys
    libc = ctypes.CDLL(None)
    libc.malloc.restype = libc.sbrk.restype = ctypes.c_void_p
    libc.malloc.argtypes, libc.free.argtypes = (ctypes.c_size_t,), (ctypes.c_void_p,)
    libc.sbrk.argtypes = (ctypes.c_ssize_t,)
    if sys.argv[1] == "keep":
        from vehicle_common.malloc_policy import keep_freed_memory
        keep_freed_memory()
    block = libc.malloc(8 * 2**20)  # a frame's buffer
    in_heap = block < libc.sbrk(0)  # from the heap, not a mapping of its own
    libc.free(block)
    top = libc.sbrk(0)
    for _ in range(5):  # the same buffer again and again: the heap does not shrink under it
        libc.free(libc.malloc(8 * 2**20))
    print(in_heap, libc.sbrk(0) >= top)
"""


def _run(mode: str) -> tuple[bool, bool]:
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(CHILD), mode],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    ).stdout.split()
    return out[-2] == "True", out[-1] == "True"


@pytest.mark.skipif(not GLIBC, reason="glibc only")
def test_a_frame_buffer_comes_from_kept_memory():
    """In a fresh process an 8 MiB block comes from the heap with the policy (and the heap keeps
    it when it is freed again and again), from a mapping of its own with glibc's defaults
    (unmapped again when freed: fresh pages the next time)."""
    kept_in_heap, kept_stays = _run("keep")
    default_in_heap, _ = _run("default")
    assert kept_in_heap and kept_stays
    assert not default_in_heap
