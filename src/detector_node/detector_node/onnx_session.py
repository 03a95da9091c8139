"""ONNX Runtime sessions of the detector's graphs (onnxruntime imported when first needed): shared
by :mod:`.onnx_detector` (no torch) and :mod:`.onnx_backend` (PyTorch's model exported)."""

from __future__ import annotations

from vehicle_common.cpu_affinity import usable_threads


def ort_session(
    graph: bytes,
    threads: int,
    level=None,
    mem_pattern: bool = True,
    arena: bool = True,
    entries: dict[str, str] | None = None,
    profile_prefix: str | None = None,
):
    """An ONNX Runtime CPU session of a serialized graph: ``threads`` intra-op threads (at most
    the CPUs this process may use: more only wait on each other), one inter-op, sequential,
    every graph optimisation, and no spinning: ONNX Runtime's idle pool threads busy-wait for
    the next operator by default, which on real KITTI 0005 (1242x375, the shipped CenterNet,
    2 threads) cost 1.6x the CPU of an inference without it, same outputs (CHANGELOG, issue
    #39); on one CPU a spinning thread also takes it from the one that works."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = usable_threads(threads)
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.graph_optimization_level = (
        ort.GraphOptimizationLevel.ORT_ENABLE_ALL if level is None else level
    )
    so.enable_mem_pattern = mem_pattern
    so.enable_cpu_mem_arena = arena
    so.log_severity_level = 3
    config = {"session.intra_op.allow_spinning": "0", "session.inter_op.allow_spinning": "0"}
    for key, value in {**config, **(entries or {})}.items():
        so.add_session_config_entry(key, value)
    if profile_prefix:
        so.enable_profiling = True
        so.profile_file_prefix = profile_prefix
    return ort.InferenceSession(graph, so, providers=["CPUExecutionProvider"])
