"""The detector's ONNX Runtime sessions: no spinning pool threads, threads within the CPUs the
process may use (issue #39: an idle intra-op thread busy-waits, costing CPU per frame)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

_SESSION = """
from onnx import TensorProto, helper
from detector_node.onnx_session import ort_session
x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])
y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])
g = helper.make_graph([helper.make_node("Relu", ["x"], ["y"])], "g", [x], [y])
m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
m.ir_version = 8
o = ort_session(m.SerializeToString(), 2).get_session_options()
print(o.intra_op_num_threads, o.get_session_config_entry("session.intra_op.allow_spinning"),
      o.get_session_config_entry("session.inter_op.allow_spinning"))
"""


def _session_settings(prefix: str = "") -> list[str]:
    code = textwrap.dedent(prefix) + _SESSION
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    )
    return out.stdout.split()


def test_sessions_do_not_spin():
    threads, intra, inter = _session_settings()
    assert (intra, inter) == ("0", "0")
    assert int(threads) == min(2, len(os.sched_getaffinity(0)))


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="Linux only")
def test_a_process_on_one_cpu_gets_one_intra_op_thread():
    """In a child process pinned to one CPU (as ``cpu_affinity: "0"`` does)."""
    cpu = min(os.sched_getaffinity(0))
    threads, _, _ = _session_settings(f"import os\nos.sched_setaffinity(0, {{{cpu}}})\n")
    assert threads == "1"


def _relu_graph() -> bytes:
    from onnx import TensorProto, helper

    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])
    g = helper.make_graph([helper.make_node("Relu", ["x"], ["y"])], "g", [x], [y])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    return m.SerializeToString()


def test_session_options_are_applied(tmp_path):
    """The node's defaults (every graph optimisation: the NCHWc layout, 2x less CPU than
    EXTENDED on the shipped CNN; memory pattern and arena on) and the variants the CPU bench
    times (bench/bench_detector_cpu.py, issue #39 item 3) reach ONNX Runtime."""
    import onnxruntime as ort
    from detector_node.onnx_session import ort_session

    level = ort.GraphOptimizationLevel
    o = ort_session(_relu_graph(), 1).get_session_options()
    assert o.graph_optimization_level == level.ORT_ENABLE_ALL
    assert (o.enable_mem_pattern, o.enable_cpu_mem_arena, o.enable_profiling) == (
        True,
        True,
        False,
    )
    s = ort_session(
        _relu_graph(),
        1,
        level=level.ORT_ENABLE_EXTENDED,
        mem_pattern=False,
        arena=False,
        entries={"session.set_denormal_as_zero": "1", "session.intra_op.allow_spinning": "1"},
        profile_prefix=str(tmp_path / "ort"),
    )
    o = s.get_session_options()
    assert o.graph_optimization_level == level.ORT_ENABLE_EXTENDED
    assert (o.enable_mem_pattern, o.enable_cpu_mem_arena, o.enable_profiling) == (
        False,
        False,
        True,
    )
    assert o.get_session_config_entry("session.set_denormal_as_zero") == "1"
    assert o.get_session_config_entry("session.intra_op.allow_spinning") == "1"
    assert o.get_session_config_entry("session.inter_op.allow_spinning") == "0"
    s.run(None, {"x": np.ones(1, np.float32)})
    assert s.end_profiling().startswith(str(tmp_path / "ort"))
