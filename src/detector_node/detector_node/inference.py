"""Running the detector on an RGB image: preprocessing, decoding and NMS."""

from __future__ import annotations

import numpy as np
import torch
from vehicle_common.node_parameters import ParameterError
from vehicle_common.orientation_bins import bin_to_alpha, fold_alpha_signed

from .boxes import decode_raw, nms
from .checkpoint import SHIPPED_CHECKPOINT, load_checkpoint
from .config import TRAINING_IMAGE_SIZE, DetectorConfig, check_roi_top, geo_frame
from .dataset import resize_image
from .detection import Detection
from .model import split_output


def choose_device(device: str = "auto") -> torch.device:
    """'auto' -> CUDA when available, else CPU; 'cpu', 'cuda' and 'cuda:N' as given. A device
    that is not there raises ParameterError (a ValueError) naming the parameter ``device``."""
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    kind, sep, index = device.partition(":")
    if device != "cpu" and not (kind == "cuda" and (not sep or index.isdigit())):
        raise ParameterError("device", f"expected auto, cpu, cuda or cuda:N, got {device!r}")
    if kind == "cuda":
        if not torch.cuda.is_available():
            raise ParameterError(
                "device", f"{device!r} requested but CUDA is not available here (use auto or cpu)"
            )
        if sep and int(index) >= torch.cuda.device_count():
            raise ParameterError(
                "device", f"{device!r}: only {torch.cuda.device_count()} CUDA device(s) here"
            )
    return torch.device(device)


def to_tensor(images: list[np.ndarray], device: torch.device) -> torch.Tensor:
    """uint8 RGB (H, W, 3) images -> float (B, 3, H, W) in [0, 1]."""
    x = torch.from_numpy(np.stack(images)).to(device)
    return x.permute(0, 3, 1, 2).float().div_(255.0)


def decode_output(
    raw: torch.Tensor,
    config: DetectorConfig,
    score_threshold: float,
    nms_iou: float,
    scale: tuple[float, float] = (1.0, 1.0),
    max_detections: int = 100,
) -> list[list[Detection]]:
    """Raw network output (B, A*9, H, W) -> detections per image, in original px (divided by
    ``scale`` = input px per original px). Score = sigmoid(objectness); class-agnostic NMS;
    orientation = argmax of the softmax over the 4 bins. CenterNet checkpoints decode with
    :func:`detector_node.centernet.decode_centernet`."""
    if config.size == "centernet":
        from .centernet import decode_centernet

        return decode_centernet(raw, config, score_threshold, nms_iou, scale, max_detections)
    out = split_output(raw.float(), config.num_anchors)
    gh, gw = out.shape[-2:]
    stride = (config.input_width / gw, config.input_height / gh)
    anchors = torch.tensor(config.anchors, dtype=out.dtype, device=out.device)
    boxes = decode_raw(out[:, :, :4], anchors, stride)  # (B, A, H, W, 4)
    scores = torch.sigmoid(out[:, :, 4])
    probs = torch.softmax(out[:, :, 5:], dim=2).permute(0, 1, 3, 4, 2)  # (B, A, H, W, 4)
    result = []
    s = np.array([scale[0], scale[1], scale[0], scale[1]])
    for i in range(out.shape[0]):
        sc = scores[i].reshape(-1).cpu().numpy()
        keep = np.nonzero(sc >= score_threshold)[0]
        bx = boxes[i].reshape(-1, 4).cpu().numpy()[keep] / s
        pr = probs[i].reshape(-1, 4).cpu().numpy()[keep]
        sc = sc[keep]
        bx[:, [0, 2]] = np.clip(bx[:, [0, 2]], 0, config.input_width / scale[0])
        bx[:, [1, 3]] = np.clip(bx[:, [1, 3]], 0, config.input_height / scale[1])
        valid = (bx[:, 2] > bx[:, 0]) & (bx[:, 3] > bx[:, 1])
        bx, pr, sc = bx[valid], pr[valid], sc[valid]
        order = nms(bx, sc, nms_iou)[:max_detections]
        result.append(
            [
                Detection(
                    box=tuple(float(v) for v in bx[j]),
                    score=float(sc[j]),
                    orientation_bin=int(np.argmax(pr[j])),
                    orientation_probs=tuple(float(p) for p in pr[j]),
                    observation_angle=float(fold_alpha_signed(bin_to_alpha(int(np.argmax(pr[j]))))),
                )
                for j in order
            ]
        )
    return result


RUNTIMES = ("auto", "torch", "onnxruntime")


def resolve_runtime(runtime: str, config: DetectorConfig, device: torch.device) -> str:
    """The inference runtime actually used: 'onnxruntime' runs the CenterNet's dense part on
    ONNX Runtime (CPU; :mod:`detector_node.onnx_backend`), 'torch' everything in PyTorch.
    'auto' = onnxruntime for a CenterNet checkpoint on the CPU when the packages are installed,
    else torch. Raises ParameterError (a ValueError) naming ``runtime`` for an unknown name or
    an impossible request."""
    if runtime not in RUNTIMES:
        raise ParameterError("runtime", f"must be one of {', '.join(RUNTIMES)}, got {runtime!r}")
    if runtime == "torch":
        return "torch"
    from .onnx_backend import onnxruntime_available

    possible = config.size == "centernet" and device.type == "cpu"
    if runtime == "auto":
        return "onnxruntime" if possible and onnxruntime_available() else "torch"
    if not possible:
        raise ParameterError(
            "runtime",
            "'onnxruntime' needs a CenterNet checkpoint on the CPU "
            f"(got {config.size} on {device.type})",
        )
    if not onnxruntime_available():
        raise ParameterError(
            "runtime", "'onnxruntime': the onnx / onnxruntime packages are not installed"
        )
    return "onnxruntime"


class CnnDetector:
    """The CNN backend: a model from a checkpoint plus its input size and inference runtime
    (``runtime``: see :func:`resolve_runtime`; ``threads``: the ONNX Runtime session's intra-op
    threads, default torch's current count)."""

    def __init__(
        self,
        model: torch.nn.Module,
        device: torch.device | str = "cpu",
        score_threshold: float = 0.3,
        nms_iou: float = 0.45,
        runtime: str = "auto",
        threads: int | None = None,
        roi_top: float | None = None,
    ) -> None:
        self.device = torch.device(device)
        self.model = model.to(self.device).eval()
        self.config = model.config
        #: the checkpoint's own configuration (set_framing derives the input's from it)
        self._checkpoint_config = model.config
        self.score_threshold = score_threshold
        self.nms_iou = nms_iou
        #: the input size the checkpoint was trained at (from_checkpoint keeps it when the
        #: input size is overridden)
        self._training_input = (self.config.input_width, self.config.input_height)
        self._training_roi_top = self.config.roi_top
        #: the runtime in use: 'torch' or 'onnxruntime'
        self.runtime = resolve_runtime(runtime, self.config, self.device)
        self._network = self.model
        if self.runtime == "onnxruntime":
            from .onnx_backend import OnnxCenterNet

            self._network = OnnxCenterNet(self.model, threads)
        #: fraction of the image height at the top that is not searched (see :meth:`detect`)
        self.roi_top = 0.0
        #: with an overridden input size: (anchors of the checkpoint, its input px per image
        #: px in training); the anchors then follow each image's scale (see from_checkpoint)
        self._anchor_reference: tuple[tuple, tuple[float, float]] | None = None
        self._scaled_configs: dict[tuple[float, float], DetectorConfig] = {}
        self.set_framing(0, 0, roi_top)

    @classmethod
    def from_checkpoint(
        cls,
        path: str = "",
        device: str = "auto",
        score_threshold: float = 0.3,
        nms_iou: float = 0.45,
        input_width: int = 0,
        input_height: int = 0,
        runtime: str = "auto",
        threads: int | None = None,
        roi_top: float | None = None,
    ) -> CnnDetector:
        """Load ``path`` ('' = the shipped checkpoint); a non-zero input size overrides the
        checkpoint's (multiples of 32; the network is fully convolutional). With an overridden
        size the anchors follow the input px per image px of each image relative to training
        (checkpoint input / TRAINING_IMAGE_SIZE): for a KITTI-sized image that is the input
        size ratio, as before; for another camera (1280x720 at 896x512) the anchors stay at the
        cars' pixel size instead of being stretched with the input's other aspect ratio."""
        dev = choose_device(device)
        model, state = load_checkpoint(path or SHIPPED_CHECKPOINT, dev)
        # the input size the weights were trained at (a checkpoint whose inference input was
        # changed afterwards keeps it as "training_input")
        trained = (model.config.input_width, model.config.input_height)
        trained = tuple(int(v) for v in state.get("training_input", trained))
        trained_roi = float(state.get("training_roi_top", model.config.roi_top))
        detector = cls(model, dev, score_threshold, nms_iou, runtime, threads, roi_top)
        detector._training_input = trained
        detector._training_roi_top = trained_roi
        detector.set_framing(input_width, input_height, roi_top)
        return detector

    def set_framing(
        self, input_width: int = 0, input_height: int = 0, roi_top: float | None = None
    ) -> None:
        """Frame the images another way: network input size (0 = the checkpoint's; multiples
        of 32: the network is fully convolutional) and the top fraction of the image left out
        (None or < 0: the checkpoint's). With an overridden size the anchors follow each
        image's input px per image px relative to training (see :meth:`from_checkpoint`). Can
        be called between images (a camera whose CameraInfo changed)."""
        c = self._checkpoint_config
        w, h = input_width or c.input_width, input_height or c.input_height
        self.roi_top = float(
            check_roi_top(c.roi_top if roi_top is None or roi_top < 0 else roi_top)
        )
        self._anchor_reference = None
        self._scaled_configs = {}
        cfg = c
        if input_width or input_height:
            sx, sy = w / c.input_width, h / c.input_height
            self._anchor_reference = (
                c.anchors,
                (c.input_width / TRAINING_IMAGE_SIZE[0], c.input_height / TRAINING_IMAGE_SIZE[1]),
            )
            cfg = DetectorConfig.from_dict(
                {
                    **c.to_dict(),
                    "input_width": w,
                    "input_height": h,
                    "anchors": [[aw * sx, ah * sy] for aw, ah in c.anchors],
                }
            )
        self.model.config = self.config = cfg

    def checkpoint_framing(self) -> tuple[tuple[int, int], float, tuple[int, int], float]:
        """(input size, roi_top) of the checkpoint and (input size, roi_top) it was trained
        at: what a camera's framing is derived from (vehicle_common.camera_settings)."""
        c = self._checkpoint_config
        return (
            (c.input_width, c.input_height),
            c.roi_top,
            tuple(self._training_input),
            self._training_roi_top,
        )

    def config_for(self, scale: tuple[float, float]) -> DetectorConfig:
        """The decoding config for an image resized by ``scale`` (input px per image px)."""
        if self._anchor_reference is None:
            return self.config
        key = (round(scale[0], 6), round(scale[1], 6))
        if key not in self._scaled_configs:
            anchors, (rx, ry) = self._anchor_reference
            fx, fy = scale[0] / rx, scale[1] / ry
            self._scaled_configs[key] = DetectorConfig.from_dict(
                {**self.config.to_dict(), "anchors": [[aw * fx, ah * fy] for aw, ah in anchors]}
            )
        return self._scaled_configs[key]

    def _geo_frame(self, width: int, height: int, top: int, scale: tuple[float, float]):
        """The orientation head's box-geometry map for this input (:func:`.config.geo_frame`)."""
        return geo_frame(
            self._training_input,
            self._training_roi_top,
            (self.config.input_width, self.config.input_height),
            width,
            height,
            top,
            scale,
        )

    @torch.no_grad()
    def detect(self, rgb: np.ndarray) -> list[Detection]:
        """Detections in an RGB uint8 image (H, W, 3), boxes in its pixels.

        With ``roi_top`` > 0 the image's top rows (that fraction of its height, above the
        region where vehicles are sought) are left out before the resize to the network input,
        and the boxes are shifted back to the full image."""
        top = int(round(self.roi_top * rgb.shape[0]))
        img, scale = resize_image(rgb[top:], self.config.input_width, self.config.input_height)
        if hasattr(self.model, "geo_frame"):
            self.model.geo_frame = self._geo_frame(rgb.shape[1], rgb.shape[0], top, scale)
        if self.runtime == "onnxruntime":
            raw = self._network.from_image(img)
        else:
            raw = self._network(to_tensor([img], self.device))
        config = self.config_for(scale)
        dets = decode_output(raw, config, self.score_threshold, self.nms_iou, scale)[0]
        if top:
            for d in dets:
                x1, y1, x2, y2 = d.box
                d.box = (x1, y1 + top, x2, y2 + top)
        return dets
