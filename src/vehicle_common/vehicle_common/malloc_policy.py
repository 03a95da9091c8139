"""Keep freed memory in a node process for reuse (glibc ``mallopt``).

A frame's large buffers (the matcher's cost volumes and filter images, several MiB each) are
allocated and freed once per frame. With glibc's defaults, blocks that large are mapped from the
kernel and unmapped again on every frame, or the top of the heap is trimmed back, so every frame
pays for fresh zeroed pages: on this project's 2-core machine the disparity map of a KITTI pair
took 24-25 ms (39 ms of CPU) this way against 16 ms (29 ms of CPU) with its memory kept, the
same map. The setting is the ``keep_freed_memory`` parameter of every node
(:func:`vehicle_common.node_runtime.apply_process_settings`), true by default: blocks below
:data:`MMAP_THRESHOLD` come from the heap and up to :data:`TRIM_THRESHOLD` of freed memory
stays there, as real-time ROS 2 processes configure malloc so that no page fault happens in
the loop. Other C libraries (no ``mallopt``) are left as they are. No rclpy here.
"""

from __future__ import annotations

import ctypes

#: blocks at least this large are still mapped from the kernel (glibc's largest allowed value)
MMAP_THRESHOLD = 32 * 2**20
#: freed memory at the top of the heap beyond this is given back to the kernel
TRIM_THRESHOLD = 128 * 2**20
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


def keep_freed_memory() -> None:
    """Set this process's malloc to keep freed blocks for reuse (see the module). RuntimeError
    where the C library has no ``mallopt`` or refuses the values."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        raise RuntimeError("the C library has no mallopt (not glibc)") from None
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    if not mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD):
        raise RuntimeError(f"mallopt refused an mmap threshold of {MMAP_THRESHOLD} bytes")
    if not mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD):
        raise RuntimeError(f"mallopt refused a trim threshold of {TRIM_THRESHOLD} bytes")
