"""ONNX Runtime sessions of the detector's graphs (onnxruntime imported when first needed): shared
by :mod:`.onnx_detector` (no torch) and :mod:`.onnx_backend` (PyTorch's model exported)."""

from __future__ import annotations


def ort_session(graph: bytes, threads: int):
    """An ONNX Runtime CPU session of a serialized graph: ``threads`` intra-op threads, one
    inter-op, sequential, every graph optimisation."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.log_severity_level = 3
    return ort.InferenceSession(graph, so, providers=["CPUExecutionProvider"])
