"""bench/bench_detector_cpu.py (issue #39 item 3): its INT8 copy of a graph runs and agrees with
the float graph (so a slow or wrong INT8 figure is ONNX Runtime's, not the tool's), and its
interleaved timing gives every variant a CPU and a wall figure."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "bench"))
import bench_detector_cpu as bdc  # noqa: E402


def _conv_graph() -> bytes:
    """uint8 NHWC image -> float NCHW -> 3x3 conv (8 channels) -> ReLU: the shipped graph's
    input contract on a tiny scale."""
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(0)
    w = rng.normal(0, 0.05, (8, 3, 3, 3)).astype(np.float32)
    b = rng.normal(0, 0.1, 8).astype(np.float32)
    nodes = [
        helper.make_node("Cast", ["image"], ["f"], to=TensorProto.FLOAT),
        helper.make_node("Transpose", ["f"], ["t"], perm=[0, 3, 1, 2]),
        helper.make_node("Conv", ["t", "w", "b"], ["c"], pads=[1, 1, 1, 1]),
        helper.make_node("Relu", ["c"], ["dense"]),
    ]
    g = helper.make_graph(
        nodes,
        "g",
        [helper.make_tensor_value_info("image", TensorProto.UINT8, [1, 16, 32, 3])],
        [helper.make_tensor_value_info("dense", TensorProto.FLOAT, [1, 8, 16, 32])],
        [numpy_helper.from_array(w, "w"), numpy_helper.from_array(b, "b")],
    )
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    return m.SerializeToString()


def _images(n: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (1, 16, 32, 3), dtype=np.uint8) for _ in range(n)]


def test_int8_copy_agrees_with_the_float_graph():
    """With 7-bit weights (``reduce_range``): AVX2 without VNNI sums u8 x s8 products in
    saturating 16-bit pairs, and full-range weights then give 14-16 % errors on this graph
    (measured on the project's 2-core machine; 1.5 % with 7 bits)."""
    graph = _conv_graph()
    q = bdc.quantized(graph, _images(8, 1), reduce_range=True)
    assert b"QuantizeLinear" in q and b"QuantizeLinear" not in graph
    f32, i8 = bdc.session(graph, 1), bdc.session(q, 1)
    for x in _images(3, 2):
        a = f32.run(None, {"image": x})[0]
        b = i8.run(None, {"image": x})[0]
        assert np.abs(a - b).max() <= 0.03 * np.abs(a).max()


def test_time_variants_times_every_variant_interleaved():
    order = []
    calls = {"a": lambda i: order.append(("a", i)), "b": lambda i: order.append(("b", i))}
    res = bdc.time_variants(calls, 2, rounds=1)
    assert set(res) == {"a", "b"} and all(len(v) == 2 for v in res.values())
    assert order[6:] == [("a", 0), ("b", 0), ("a", 1), ("b", 1)]  # after 3 warm-up calls each
