"""numpy's BLAS (OpenBLAS) on one thread in a node process.

numpy's bundled OpenBLAS starts one thread per core and, after each multi-threaded call, lets
them spin waiting for more work. In a node that multiplies a few small matrices per frame (the
detector's orientation head on its boxes: (N, 1155) x (1155, 64)) the spinning is most of the
cost: on real KITTI 0005 the detector process used 86-111 ms of CPU per frame with 37 ms of CNN
(docs/RESULTS.md, issue #33), 43 ms with OpenBLAS on one thread. ``OPENBLAS_NUM_THREADS`` is read
only when numpy is imported, so the node sets the thread count at run time through OpenBLAS's own
setter, as threadpoolctl does. The nodes' parallel work is in OpenCV and ONNX Runtime, whose
threads their ``num_threads`` parameters set.
"""

from __future__ import annotations

import ctypes

#: OpenBLAS's setter under the names of its builds (numpy's scipy-openblas64, plain OpenBLAS)
_SETTERS = (
    "scipy_openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads",
    "openblas_set_num_threads64_",
    "openblas_set_num_threads",
)
_GETTERS = (
    "scipy_openblas_get_num_threads64_",
    "scipy_openblas_get_num_threads",
    "openblas_get_num_threads64_",
    "openblas_get_num_threads",
)


def _openblas_libraries() -> list[ctypes.CDLL]:
    import numpy  # noqa: F401  (loads its OpenBLAS)

    paths = []
    try:
        with open("/proc/self/maps") as maps:
            for line in maps:
                path = line.split()[-1] if len(line.split()) >= 6 else ""
                if "openblas" in path.rsplit("/", 1)[-1].lower() and path not in paths:
                    paths.append(path)
    except OSError:
        return []
    libs = []
    for path in paths:
        try:
            libs.append(ctypes.CDLL(path))
        except OSError:
            continue
    return libs


def _function(lib: ctypes.CDLL, names: tuple[str, ...]):
    for name in names:
        fn = getattr(lib, name, None)
        if fn is not None:
            return fn
    return None


def set_blas_threads(n: int) -> bool:
    """Set the thread count of every OpenBLAS loaded in this process; False when none is (or
    none has a setter: another BLAS)."""
    done = False
    for lib in _openblas_libraries():
        setter = _function(lib, _SETTERS)
        if setter is not None:
            setter.restype = None
            setter(ctypes.c_int(n))
            done = True
    return done


def blas_threads() -> int | None:
    """The thread count of the first OpenBLAS loaded in this process (None: none)."""
    for lib in _openblas_libraries():
        getter = _function(lib, _GETTERS)
        if getter is not None:
            getter.restype = ctypes.c_int
            return int(getter())
    return None
