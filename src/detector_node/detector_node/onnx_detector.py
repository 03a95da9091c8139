"""The CenterNet detector on ONNX Runtime without PyTorch (the detector node's CPU path).

:class:`OnnxCenterNetDetector` runs the dense part of the network from the ONNX graph and the
sparse part in numpy (:mod:`detector_node.centernet_decode`); it gives the detections of
:class:`detector_node.inference.CnnDetector` with ``runtime="onnxruntime"`` (same framing,
region of interest, orientation geometry). What it needs from the checkpoint -- configuration,
training framing, orientation head, and the ONNX graph per input size -- comes from the user
cache (:mod:`detector_node.onnx_cache`); only on a miss is PyTorch imported, the checkpoint
loaded and the graph written (then cached). Pure: no rclpy.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .centernet_decode import OrientationHead, decode_dense
from .config import DetectorConfig, check_roi_top, geo_frame
from .dataset import resize_image
from .detection import Detection
from .onnx_cache import OnnxCache, array_json, json_array
from .onnx_session import ort_session

#: names of the ONNX graph's input and outputs (as detector_node.onnx_backend writes them)
INPUT = "image"


@dataclass(frozen=True)
class CheckpointInfo:
    """What inference needs of a checkpoint besides the dense graph: its configuration, the
    framing it was trained at, the orientation head (CenterNet)."""

    config: DetectorConfig
    training_input: tuple[int, int]
    training_roi_top: float
    head: OrientationHead | None = None

    def arrays(self) -> dict[str, np.ndarray]:
        out = {
            "config": json_array(self.config.to_dict()),
            "training": json_array(
                {"input": list(self.training_input), "roi_top": self.training_roi_top}
            ),
        }
        if self.head is not None:
            out.update({f"head_{k}": v for k, v in self.head.arrays().items()})
        return out

    @classmethod
    def from_arrays(cls, arrays) -> CheckpointInfo:
        training = array_json(arrays["training"])
        head = None
        if "head_w1" in arrays:
            head = OrientationHead.from_arrays(
                {k: arrays[f"head_{k}"] for k in ("w1", "b1", "w2", "b2")}
            )
        return cls(
            DetectorConfig.from_dict(array_json(arrays["config"])),
            tuple(int(v) for v in training["input"]),
            float(training["roi_top"]),
            head,
        )

    @classmethod
    def from_model(cls, model, state: dict) -> CheckpointInfo:
        """From a loaded checkpoint (``detector_node.checkpoint.load_checkpoint``)."""
        c = model.config
        trained = tuple(
            int(v) for v in state.get("training_input", (c.input_width, c.input_height))
        )
        head = None
        if c.size == "centernet":
            first, last = model.orientation[0], model.orientation[-1]

            def arr(t):
                return t.detach().cpu().numpy().astype(np.float32)

            head = OrientationHead(
                arr(first.weight), arr(first.bias), arr(last.weight), arr(last.bias)
            )
        return cls(c, trained, float(state.get("training_roi_top", c.roi_top)), head)


class CheckpointSource:
    """A checkpoint file and its cache entries: :meth:`info` and :meth:`onnx_graph` read the
    cache and, on a miss, load the checkpoint with PyTorch (once) and write the entry."""

    def __init__(self, path: str | os.PathLike, digest: str, cache: OnnxCache) -> None:
        self.path = Path(path)
        self.digest = digest
        self.cache = cache
        self._loaded = None  # (model, state) once PyTorch loaded the checkpoint
        #: what was built because the cache did not have it ("info", "onnx 896x224", ...)
        self.built: list[str] = []

    def _model(self):
        if self._loaded is None:
            from .checkpoint import load_checkpoint

            self._loaded = load_checkpoint(self.path, "cpu")
        return self._loaded

    def info(self) -> CheckpointInfo:
        name = self.cache.key(self.digest, "meta")
        arrays = self.cache.read(name)
        if arrays is not None:
            try:
                return CheckpointInfo.from_arrays(arrays)
            except (KeyError, ValueError, TypeError):
                pass  # a cache entry of another layout: rebuilt below
        info = CheckpointInfo.from_model(*self._model())
        self.cache.write(name, info.arrays())
        self.built.append("checkpoint info")
        return info

    def onnx_graph(self, height: int, width: int) -> bytes:
        """The serialized ONNX graph of the dense part at a uint8 image input of this size."""
        name = self.cache.key(self.digest, f"onnx{width}x{height}")
        arrays = self.cache.read(name)
        if arrays is not None and "onnx" in arrays:
            return arrays["onnx"].tobytes()
        from .onnx_backend import centernet_to_onnx

        graph = centernet_to_onnx(self._model()[0], height, width, image_input=True)
        self.cache.write(name, {"onnx": np.frombuffer(graph, np.uint8)})
        self.built.append(f"ONNX graph {width}x{height}")
        return graph


class OnnxCenterNetDetector:
    """A CenterNet checkpoint on ONNX Runtime (dense part) and numpy (sparse part), no
    PyTorch: the interface of :class:`detector_node.inference.CnnDetector` (``detect``,
    ``set_framing``, ``config``, ``roi_top``, ``runtime``, ``device``)."""

    runtime = "onnxruntime"
    device = "cpu"

    def __init__(
        self,
        source: CheckpointSource,
        info: CheckpointInfo,
        score_threshold: float = 0.3,
        nms_iou: float = 0.45,
        threads: int | None = None,
    ) -> None:
        if info.config.size != "centernet" or info.head is None:
            raise ValueError(f"{source.path}: not a CenterNet checkpoint")
        self.source = source
        self.info = info
        self.score_threshold = score_threshold
        self.nms_iou = nms_iou
        self.threads = threads or os.cpu_count() or 1
        self._sessions: dict[tuple[int, int], object] = {}
        self.config = info.config
        self.roi_top = float(info.config.roi_top)

    def set_framing(
        self, input_width: int = 0, input_height: int = 0, roi_top: float | None = None
    ) -> None:
        """Network input size (0 = the checkpoint's) and the top fraction of the image left
        out (None or < 0: the checkpoint's); the graph of a new size is read from the cache
        (or built) at the next image."""
        c = self.info.config
        w, h = input_width or c.input_width, input_height or c.input_height
        self.roi_top = float(
            check_roi_top(c.roi_top if roi_top is None or roi_top < 0 else roi_top)
        )
        if (w, h) != (c.input_width, c.input_height):
            c = DetectorConfig.from_dict({**c.to_dict(), "input_width": w, "input_height": h})
        self.config = c

    def checkpoint_framing(self) -> tuple[tuple[int, int], float, tuple[int, int], float]:
        """As :meth:`detector_node.inference.CnnDetector.checkpoint_framing`."""
        c = self.info.config
        return (
            (c.input_width, c.input_height),
            c.roi_top,
            self.info.training_input,
            self.info.training_roi_top,
        )

    def session(self, height: int, width: int):
        """The ONNX Runtime session of this input size (one per size, kept)."""
        key = (height, width)
        if key not in self._sessions:
            self._sessions[key] = ort_session(self.source.onnx_graph(height, width), self.threads)
        return self._sessions[key]

    def detect(self, rgb: np.ndarray) -> list[Detection]:
        """Detections in an RGB uint8 image (H, W, 3), boxes in its pixels (the top
        ``roi_top`` of the image left out, as :meth:`CnnDetector.detect`)."""
        c = self.config
        height, width = rgb.shape[:2]
        top = int(round(self.roi_top * height))
        img, scale = resize_image(rgb[top:], c.input_width, c.input_height)
        feature, dense = self.session(c.input_height, c.input_width).run(
            None, {INPUT: np.ascontiguousarray(img, np.uint8)[None]}
        )
        geo = geo_frame(
            self.info.training_input,
            self.info.training_roi_top,
            (c.input_width, c.input_height),
            width,
            height,
            top,
            scale,
        )
        dets = decode_dense(
            feature,
            dense,
            self.info.head,
            (c.input_width, c.input_height),
            self.score_threshold,
            self.nms_iou,
            scale,
            geo,
        )
        if top:
            for d in dets:
                x1, y1, x2, y2 = d.box
                d.box = (x1, y1 + top, x2, y2 + top)
        return dets
