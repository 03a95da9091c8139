"""Loading the CNN detector the way the node and ``detector_offline`` do (pure: no rclpy, and
no torch unless the chosen runtime needs it).

:func:`load_detector` returns :class:`~detector_node.onnx_detector.OnnxCenterNetDetector` (ONNX
Runtime and numpy, no PyTorch, from the user cache) for a CenterNet checkpoint on the CPU with
runtime ``auto`` or ``onnxruntime`` when ONNX Runtime is installed, else
:class:`~detector_node.inference.CnnDetector` (PyTorch), exactly the choice of
:func:`detector_node.inference.resolve_runtime`. Both have ``detect``, ``set_framing``,
``config``, ``roi_top``, ``runtime`` and ``device``.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from vehicle_common.node_parameters import ParameterError

from .checkpoint import SHIPPED_CHECKPOINT, CheckpointError, resolve_checkpoint
from .onnx_cache import OnnxCache, cache_dir, file_digest

RUNTIMES = ("auto", "torch", "onnxruntime")
DEVICES = ("auto", "cpu", "cuda")
#: device files of a GPU PyTorch could use (NVIDIA, WSL2's, AMD ROCm's)
_GPU_DEVICE_FILES = ("/dev/nvidiactl", "/dev/nvidia0", "/dev/dxg", "/dev/kfd")


def gpu_present() -> bool:
    """Whether this machine has a GPU device PyTorch could use (without importing PyTorch:
    with none, ``device: auto`` is the CPU)."""
    return any(Path(p).exists() for p in _GPU_DEVICE_FILES)


def onnxruntime_installed() -> bool:
    """Whether the ``onnx`` and ``onnxruntime`` packages are installed (not imported)."""
    return all(importlib.util.find_spec(m) is not None for m in ("onnx", "onnxruntime"))


def checkpoint_path(checkpoint: str = "") -> Path:
    """The file of ``checkpoint`` ('' = the shipped one; a name such as ``tiny_kitti``; a
    path). Raises CheckpointError (one line naming it) when it is missing or a folder."""
    path = resolve_checkpoint(checkpoint or SHIPPED_CHECKPOINT)
    if path.is_dir():
        raise CheckpointError(f"{path}: is a folder, not a checkpoint file")
    if not path.is_file():
        raise CheckpointError(f"{path}: checkpoint not found")
    return path


def load_detector(
    checkpoint: str = "",
    device: str = "auto",
    score_threshold: float = 0.3,
    nms_iou: float = 0.45,
    input_width: int = 0,
    input_height: int = 0,
    runtime: str = "auto",
    threads: int | None = None,
    roi_top: float | None = None,
    cache: OnnxCache | None = None,
):
    """The CNN detector of ``checkpoint`` ('' = the shipped one) with the node's settings (see
    the module docstring; ``cache``: default the user cache folder). Raises ValueError naming
    the setting or file at fault."""
    if runtime not in RUNTIMES:
        raise ParameterError("runtime", f"must be one of {', '.join(RUNTIMES)}, got {runtime!r}")
    path = checkpoint_path(checkpoint)
    cpu = device == "cpu" or (device == "auto" and not gpu_present())
    if runtime != "torch" and cpu and onnxruntime_installed():
        from .onnx_detector import CheckpointSource, OnnxCenterNetDetector

        try:
            digest = file_digest(path)
        except OSError as exc:
            raise CheckpointError(f"{path}: cannot read the checkpoint ({exc})") from None
        source = CheckpointSource(path, digest, cache or OnnxCache(cache_dir()))
        info = source.info()
        if info.config.size == "centernet":
            det = OnnxCenterNetDetector(source, info, score_threshold, nms_iou, threads)
            det.set_framing(input_width, input_height, roi_top)
            return det
    from .inference import CnnDetector

    # PyTorch: the runtime torch, a GPU, a checkpoint that is not a CenterNet, or no ONNX
    # Runtime (CnnDetector.from_checkpoint reports an impossible 'onnxruntime' request)
    return CnnDetector.from_checkpoint(
        str(path),
        device,
        score_threshold,
        nms_iou,
        input_width,
        input_height,
        runtime=runtime,
        threads=threads,
        roi_top=roi_top,
    )


def checkpoint_framing(checkpoint: str = "", cache: OnnxCache | None = None):
    """(config, training input (w, h), training roi_top) of a checkpoint, from the user cache
    when it holds it (no PyTorch), for deriving a camera's settings offline."""
    from .onnx_detector import CheckpointSource

    path = checkpoint_path(checkpoint)
    info = CheckpointSource(path, file_digest(path), cache or OnnxCache(cache_dir())).info()
    return info.config, info.training_input, info.training_roi_top


def load_node_detector(p) -> tuple[object, str, str | None]:
    """The node's CNN detector of its parameters ``p`` (:class:`.parameters.DetectorParameters`;
    PyTorch's threads set to ``p.num_threads``, at most the CPUs the process may use, when it
    runs it), its info line and, for a CenterNet on PyTorch on the CPU that could run on ONNX
    Runtime, a warning line (else None).
    A checkpoint that cannot be used: ParameterError naming ``checkpoint``."""
    try:  # device and runtime raise ParameterError themselves
        cnn = load_detector(
            p.checkpoint,
            p.device,
            p.score_threshold,
            p.nms_iou,
            p.input_width,
            p.input_height,
            runtime=p.runtime,
            threads=p.num_threads,
            roi_top=p.roi_top,
        )
    except CheckpointError as exc:
        raise ParameterError("checkpoint", str(exc)) from None
    if cnn.runtime == "torch":
        import torch
        from vehicle_common.cpu_affinity import usable_threads

        torch.set_num_threads(usable_threads(p.num_threads))
    c = cnn.config
    built = getattr(getattr(cnn, "source", None), "built", [])
    info = (
        f"cnn backend: {c.size} model (width {c.width}, depth {c.depth}), device "
        f"{cnn.device}, runtime {cnn.runtime}"
        + (f"; built and cached: {', '.join(built)}" if built else "")
    )
    warning = None
    if (
        c.size == "centernet"
        and p.runtime == "auto"
        and str(cnn.device) == "cpu"  # on a GPU, PyTorch is the right choice
        and cnn.runtime == "torch"
    ):
        warning = (
            "onnx / onnxruntime not installed: the CenterNet runs on PyTorch, about 3x "
            "slower (pip install onnx==1.23.1 onnxruntime==1.30.0; scripts/setup.sh "
            "installs them)"
        )
    return cnn, info, warning
