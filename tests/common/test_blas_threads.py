"""numpy's OpenBLAS on one thread in a node process (issue #33: its spinning threads doubled the
detector's CPU per frame on real data)."""

import subprocess
import sys

import pytest


def test_set_blas_threads_sets_numpy_openblas():
    code = (
        "from vehicle_common.blas_threads import blas_threads, set_blas_threads\n"
        "before = blas_threads()\n"
        "ok = set_blas_threads(1)\n"
        "print(before, ok, blas_threads())\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        env={"PATH": "/usr/bin:/bin", "OPENBLAS_NUM_THREADS": "2"},
    ).stdout.split()
    if out[0] == "None":
        pytest.skip("numpy is not built on OpenBLAS here")
    assert out == ["2", "True", "1"]


def test_every_node_runs_numpy_blas_on_one_thread(rclpy_context):
    from rclpy.node import Node
    from vehicle_common.blas_threads import blas_threads, set_blas_threads
    from vehicle_common.node_runtime import apply_process_settings

    if blas_threads() is None:
        pytest.skip("numpy is not built on OpenBLAS here")
    set_blas_threads(2)
    node = Node("blas_threads_test", context=rclpy_context)
    try:
        apply_process_settings(node)
        assert blas_threads() == 1
    finally:
        node.destroy_node()
