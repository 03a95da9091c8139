"""Checkpoints: tensors + model config, loadable with ``torch.load(weights_only=True)``."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # torch is imported where a checkpoint is read or written: the file names
    # below serve the ONNX Runtime path, which runs without it
    import torch

    from .model import YoloV2Passthrough


def _shipped_checkpoint() -> Path:
    """The shipped checkpoint: ``src/detector_node/models/`` in the source tree (editable
    install), else ``share/detector_node/models/`` of a colcon/ament install."""
    source = Path(__file__).resolve().parent.parent / "models" / "centernet_kitti.pt"
    if source.is_file():
        return source
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("detector_node")) / "models" / source.name
    except (ImportError, LookupError, OSError):  # OSError: AMENT_PREFIX_PATH unset
        return source


#: The default checkpoint shipped in the repository: the pretrained CenterNet (@vladmandic/human
#: 3.3.6, COCO) with its orientation head trained on real KITTI frames; the previous default
#: ``tiny_kitti.pt`` (YOLOv2 tiny) stays beside it, loadable by name (model cards:
#: docs/detector.md).
SHIPPED_CHECKPOINT = _shipped_checkpoint()
FORMAT_VERSION = 1


def save_checkpoint(
    path: str | os.PathLike,
    model: YoloV2Passthrough,
    extra: dict | None = None,
) -> None:
    """Save the weights, the config (dict of plain values) and optional plain extras
    (epoch, optimizer state, metrics...)."""
    import torch

    state = {
        "format_version": FORMAT_VERSION,
        "config": model.config.to_dict(),
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
    }
    if getattr(model, "topology", None) is not None:  # CenterNet: the graph travels along
        state["graph"] = json.dumps(model.topology)
    if extra:
        state.update(extra)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)


def resolve_checkpoint(name: str | os.PathLike) -> Path:
    """A checkpoint file, or a shipped model by name (``tiny_kitti`` / ``tiny_kitti.pt``,
    ``centernet_kitti``: a bare name that is not an existing file is looked up in the shipped
    models folder)."""
    path = Path(name)
    if path.is_file() or path.parent != Path("."):
        return path
    shipped = SHIPPED_CHECKPOINT.parent / (path.name if path.suffix == ".pt" else f"{path}.pt")
    return shipped if shipped.is_file() else path


class CheckpointError(ValueError):
    """A checkpoint file is missing, unreadable or not a detector checkpoint; the message (one
    line) names the file."""


def _reason(exc: Exception) -> str:
    """The gist of a loading error in one short line (torch's unpickling errors span many lines
    of advice; the line after 'WeightsUnpickler error:' says what was found)."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    for i, line in enumerate(lines[:-1]):
        if line.endswith("WeightsUnpickler error:"):
            return lines[i + 1]
    text = lines[0] if lines else type(exc).__name__
    return text if len(text) <= 160 else text[:157] + "..."


def load_checkpoint(
    path: str | os.PathLike, device: str | torch.device = "cpu"
) -> tuple[torch.nn.Module, dict]:
    """Load a checkpoint safely (``weights_only=True``); returns (model in eval mode, raw dict).

    Raises CheckpointError (a ValueError) naming the file, in one line, when it is missing, is
    not a PyTorch file, or is not a detector checkpoint whose weights fit its model.
    """
    import torch

    from .model import DetectorConfig, YoloV2Passthrough

    path = resolve_checkpoint(path)
    if path.is_dir():
        raise CheckpointError(f"{path}: is a folder, not a checkpoint file")
    if not path.is_file():
        raise CheckpointError(f"{path}: checkpoint not found")
    try:
        state = torch.load(path, map_location=device, weights_only=True)
    except Exception as exc:  # unpickling errors come in many types
        raise CheckpointError(
            f"{path}: not a PyTorch weights-only checkpoint ({_reason(exc)})"
        ) from None
    if not isinstance(state, dict) or "config" not in state or "state_dict" not in state:
        raise CheckpointError(f"{path}: not a detector checkpoint (config/state_dict missing)")
    try:
        config = DetectorConfig.from_dict(state["config"])
        if config.size == "centernet":
            from .centernet import CenterNetDetector

            if "graph" not in state:
                raise CheckpointError(f"{path}: CenterNet checkpoint without its graph")
            model = CenterNetDetector(config, json.loads(state["graph"]), None)
        else:
            model = YoloV2Passthrough(config)
        model.load_state_dict(state["state_dict"])
    except CheckpointError:
        raise
    except Exception as exc:  # a config or weights that do not fit the model
        raise CheckpointError(
            f"{path}: not a usable detector checkpoint ({_reason(exc)})"
        ) from None
    if config.size == "centernet":
        model.graph.fuse()  # the constants' values are known now
    model.to(device).eval()
    return model, state


def set_inference_framing(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    input_width: int,
    input_height: int,
    roi_top: float,
) -> None:
    """Copy a CenterNet checkpoint with another inference framing: network input size and the
    top fraction of the image left out (``DetectorConfig.roi_top``). The weights are unchanged;
    the framing they were trained at is kept as ``training_input`` and ``training_roi_top`` (the
    orientation head's box geometry refers to it: ``CnnDetector._geo_frame``)."""
    import torch

    from .model import DetectorConfig

    model, state = load_checkpoint(src)  # the same checks and one-line errors
    config = model.config
    if config.size != "centernet":
        raise ValueError(
            f"{resolve_checkpoint(src)}: only CenterNet checkpoints are fully convolutional here"
        )
    state.setdefault("training_input", [config.input_width, config.input_height])
    state.setdefault("training_roi_top", config.roi_top)
    new = DetectorConfig.from_dict(
        {
            **config.to_dict(),
            "input_width": input_width,
            "input_height": input_height,
            "roi_top": roi_top,
        }
    )
    state["config"] = new.to_dict()
    dst = Path(dst)
    tmp = dst.with_suffix(dst.suffix + ".tmp")
    torch.save(state, tmp)
    os.replace(tmp, dst)
