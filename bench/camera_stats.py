"""The shipped CNN's detection statistics on real labelled frames it is not trained on.

Used by ``bench/bench_tracker.py real --source camera`` (issue 23's camera benchmark). The
detector as the node loads it (``detector_node.loading.load_detector``: the
``vehicle_detector`` node's inference, the graph's score threshold and NMS) runs offline on
the detector VALIDATION frames fixed by the lead (interfaces.md): every frame of tracking
sequences 0005 and 0001 here, the
``tracking_keyframes`` of 0005, 0001, 0008 and 0010, and the object frames that are frames of
these sequences (``detector_node.real_split.REPORT_OBJECT_IDS`` since issue 34, when these four
sequences became the detector's reporting split; object frames 000060-000079 before); frames
of ``detector_node.real_split``'s training tracking sequences and object ids are left out
(the split of the current checkpoint: the former one trained on 8 of those 11 object frames).
Detections are matched to the labels (2D IoU >= 0.5, by score); the statistics, per labelled
Car:

- miss rate by box height and by occlusion level (a Car is detected when a detection matches
  it); truncated Cars (truncation > 0.3) and Cars under 10 px are kept apart;
- box noise by box height: median and 1.4826 MAD of each edge's error (x1, y1, x2, y2) [px];
- the scores of the detections that matched a Car, by box height and occlusion (none / some);
- orientation confusion: labelled bin (alpha) x detected bin, 4 x 4 counts;
- false positives per frame: detections matching no labelled vehicle (Car, Van, Truck, Tram
  with IoU >= 0.3) and lying not mostly (> 50 %) inside a DontCare region; their boxes and
  scores (and the stereo plausibility when the detections carry it: not yet).

Cached as JSON under ``.cache/camera_stats/`` (git-ignored) keyed by the checkpoint file's
SHA-256, the detector settings and the frame list, so a new checkpoint is measured once when
the benchmark next runs.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from detector_node.real_split import REPORT_OBJECT_IDS

REPO = Path(__file__).resolve().parent.parent
KITTI = REPO.parent / "shared" / "kitti"
CACHE = REPO / ".cache" / "camera_stats"
#: The detector VALIDATION frames of interfaces.md (lead's decision 4)
VALIDATION_SEQUENCES = ("0005", "0001")  # every frame of these here
VALIDATION_KEYFRAME_SEQUENCES = ("0005", "0001", "0008", "0010")
#: the object frames that are frames of these sequences (detector_node.real_split, issue 34;
#: object 60-79 until then)
VALIDATION_OBJECT_IDS = REPORT_OBJECT_IDS
HEIGHT_BINS = (0.0, 25.0, 40.0, 60.0, 100.0, math.inf)  # [px] box height
VEHICLES = ("Car", "Van", "Truck", "Tram")
SCHEMA = 3


@dataclass
class LabelledFrame:
    name: str
    image: Path
    objects: list  # KittiObject labels (DontCare included)


def validation_frames(kitti: Path = KITTI) -> list[LabelledFrame]:
    """The VALIDATION frames present under ``kitti``, minus the checkpoint's training frames."""
    from vehicle_common.kitti import read_object_labels, read_tracking_labels

    from detector_node import real_split

    # whole tracking sequences the shipped checkpoint trained on (none since the pretrained
    # CenterNet: it trains on keyframes of other sequences; tiny_kitti.pt trained on 0001)
    trained_seqs = set(getattr(real_split, "TRAIN_TRACKING_SEQUENCES", ()))
    trained_ids = set(real_split.TRAIN_OBJECT_ID_LIST)
    tracking = kitti / "tracking" / "training"
    out, seen = [], set()
    for seq in VALIDATION_SEQUENCES:
        if seq in trained_seqs or not (tracking / "image_02" / seq).is_dir():
            continue
        labels = read_tracking_labels(tracking / "label_02" / f"{seq}.txt")
        for png in sorted((tracking / "image_02" / seq).glob("*.png")):
            k = int(png.stem)
            out.append(LabelledFrame(f"{seq}/{k:06d}", png, labels.get(k, [])))
            seen.add((seq, k))
    kf = kitti / "tracking_keyframes"
    if (kf / "frames.csv").is_file():
        with open(kf / "frames.csv") as fh:
            rows = list(csv.DictReader(fh))
        labels_of = {}
        for r in rows:
            seq, k = r["tracking_sequence"], int(r["tracking_frame"])
            if seq not in VALIDATION_KEYFRAME_SEQUENCES or (seq, k) in seen:
                continue
            if seq not in labels_of:
                labels_of[seq] = read_tracking_labels(tracking / "label_02" / f"{seq}.txt")
            png = kf / "image_2" / f"{r['name']}.png"
            out.append(LabelledFrame(f"kf/{r['name']}", png, labels_of[seq].get(k, [])))
    obj = kitti / "object" / "training"
    for i in VALIDATION_OBJECT_IDS:
        png, lab = obj / "image_2" / f"{i:06d}.png", obj / "label_2" / f"{i:06d}.txt"
        if i not in trained_ids and png.is_file() and lab.is_file():
            out.append(LabelledFrame(f"object/{i:06d}", png, read_object_labels(lab)))
    return out


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """2D IoU matrix of boxes (N, 4) x (M, 4)."""
    if not len(a) or not len(b):
        return np.zeros((len(a), len(b)))
    x1 = np.maximum(a[:, None, 0], b[None, :, 0])
    y1 = np.maximum(a[:, None, 1], b[None, :, 1])
    x2 = np.minimum(a[:, None, 2], b[None, :, 2])
    y2 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    return inter / np.maximum(area_a[:, None] + area_b[None, :] - inter, 1e-9)


def _inside_fraction(a: np.ndarray, regions: np.ndarray) -> np.ndarray:
    """Largest share of each box's area (N,) inside one of ``regions`` (M, 4)."""
    if not len(a) or not len(regions):
        return np.zeros(len(a))
    x1 = np.maximum(a[:, None, 0], regions[None, :, 0])
    y1 = np.maximum(a[:, None, 1], regions[None, :, 1])
    x2 = np.minimum(a[:, None, 2], regions[None, :, 2])
    y2 = np.minimum(a[:, None, 3], regions[None, :, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    area = np.maximum((a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1]), 1e-9)
    return (inter / area[:, None]).max(axis=1)


def height_bin(h: float) -> int:
    return int(np.searchsorted(HEIGHT_BINS, h, side="right") - 1)


def match_frame(objects, boxes: np.ndarray, scores: np.ndarray) -> dict:
    """Detections (boxes (M, 4), scores (M,)) of one frame against its labels: per labelled
    Car its detection (index or -1), and the detections that are false positives."""
    cars = [o for o in objects if o.type == "Car"]
    others = [o for o in objects if o.type in VEHICLES and o.type != "Car"]
    dontcare = np.array([o.bbox for o in objects if o.is_dontcare]).reshape(-1, 4)
    g = np.array([o.bbox for o in cars]).reshape(-1, 4)
    iou = _iou(g, boxes)
    det_of = np.full(len(cars), -1)
    taken = np.zeros(len(boxes), bool)
    for j in np.argsort(-scores):  # by score, each detection to its best free Car
        if not len(cars):
            break
        cand = np.where(det_of < 0, iou[:, j], 0.0)
        i = int(np.argmax(cand))
        if cand[i] >= 0.5:
            det_of[i], taken[j] = j, True
    vehicle = np.array([o.bbox for o in cars + others]).reshape(-1, 4)
    near = _iou(boxes, vehicle).max(axis=1) >= 0.3 if len(vehicle) else np.zeros(len(boxes), bool)
    fp = ~taken & ~near & (_inside_fraction(boxes, dontcare) <= 0.5)
    return {"cars": cars, "det_of": det_of, "fp": np.nonzero(fp)[0]}


def _consecutive(a: str, b: str) -> bool:
    """Whether frame names ``SEQ/NNNNNN`` ``a`` and ``b`` are successive frames of a sequence."""
    sa, _, fa = a.partition("/")
    sb, _, fb = b.partition("/")
    return sa == sb and sa.isdigit() and fa.isdigit() and fb.isdigit() and int(fb) == int(fa) + 1


def checkpoint_path(checkpoint: str = "") -> Path:
    from detector_node.checkpoint import SHIPPED_CHECKPOINT

    return Path(checkpoint) if checkpoint else Path(SHIPPED_CHECKPOINT)


def _sha256(path: Path) -> str:
    from detector_node.onnx_cache import file_digest

    return file_digest(path)


def detector_settings() -> dict:
    """The graph's detector settings (score threshold, NMS, input size) from
    tracking_bringup/config/pipeline.params.yaml."""
    import yaml

    p = REPO / "src" / "tracking_bringup" / "config" / "pipeline.params.yaml"
    d = yaml.safe_load(p.read_text())["vehicle_detector"]["ros__parameters"]
    keys = ("score_threshold", "nms_iou", "input_width", "input_height")
    return {k: d[k] for k in keys}


def measure(checkpoint: str = "", verbose: bool = True) -> dict:
    """The statistics (see the module docstring) of ``checkpoint`` ('' = the shipped one),
    from the cache when this checkpoint, these settings and these frames were measured."""
    ck = checkpoint_path(checkpoint)
    frames = validation_frames()
    settings = detector_settings()
    key_src = json.dumps(
        {
            "schema": SCHEMA,
            "checkpoint": _sha256(ck),
            "settings": settings,
            "frames": [f.name for f in frames],
        },
        sort_keys=True,
    )
    key = hashlib.sha256(key_src.encode()).hexdigest()[:16]
    path = CACHE / f"{_sha256(ck)[:16]}-{key}.json"
    if path.is_file():
        stats = json.loads(path.read_text())
        if verbose:
            print(f"camera statistics: {path} (cached; checkpoint {ck.name} sha256 {stats['sha']})")
        return stats
    stats = _measure(ck, frames, settings, verbose)
    stats["sha"] = _sha256(ck)[:16]
    CACHE.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(stats, indent=1))
    if verbose:
        print(f"camera statistics written to {path}")
    return stats


def _measure(ck: Path, frames: list[LabelledFrame], settings: dict, verbose: bool) -> dict:
    import torch
    from detector_node.loading import load_detector
    from vehicle_common.kitti import read_png
    from vehicle_common.orientation_bins import alpha_to_bin

    torch.set_num_threads(1)
    det = load_detector(str(ck), device="cpu", **settings)
    nb = len(HEIGHT_BINS) - 1
    found = np.zeros((nb, 4))  # [height bin, occlusion 0..3] detected
    total = np.zeros((nb, 4))
    trunc = [0, 0]  # truncated Cars: detected, total
    edge_err = [[] for _ in range(nb)]
    tp_score = [[] for _ in range(nb)]
    tp_score_occluded = [[] for _ in range(nb)]  # labelled occlusion >= 1
    confusion = np.zeros((4, 4), int)
    fp_boxes, fp_scores, fp_counts = [], [], []
    persist = [0, 0]  # false positives of a sequence frame seen again in the next: n, of
    prev_name, prev_fp = None, np.zeros((0, 4))
    t0 = time.perf_counter()
    for fr in frames:
        rgb = read_png(fr.image)
        dets = det.detect(rgb)
        boxes = np.array([d.box for d in dets], float).reshape(-1, 4)
        scores = np.array([d.score for d in dets], float)
        bins = np.array([d.orientation_bin for d in dets], int)
        m = match_frame(fr.objects, boxes, scores)
        for o, j in zip(m["cars"], m["det_of"], strict=True):
            if o.truncated > 0.3:
                trunc[0] += int(j >= 0)
                trunc[1] += 1
                continue
            b, occ = height_bin(o.height_px), min(max(int(o.occluded), 0), 3)
            total[b, occ] += 1
            if j < 0:
                continue
            found[b, occ] += 1
            edge_err[b].append((boxes[j] - np.array(o.bbox)).tolist())
            (tp_score_occluded if occ else tp_score)[b].append(float(scores[j]))
            if o.alpha > -math.pi - 1e-6:
                confusion[int(alpha_to_bin(o.alpha)), int(bins[j])] += 1
        fp_counts.append(len(m["fp"]))
        fp_now = boxes[m["fp"]].reshape(-1, 4)
        if prev_name is not None and _consecutive(prev_name, fr.name):
            # a false positive on the static background is found again in the next frame
            persist[0] += (
                int((_iou(prev_fp, fp_now).max(axis=1) >= 0.3).sum()) if len(fp_now) else 0
            )
            persist[1] += len(prev_fp)
        prev_name, prev_fp = fr.name, fp_now
        for j in m["fp"]:
            fp_boxes.append(boxes[j].tolist())
            fp_scores.append(float(scores[j]))
    elapsed = time.perf_counter() - t0
    if verbose:
        print(f"  detector ran on {len(frames)} frames in {elapsed:.0f} s")
    return {
        "frames": [f.name for f in frames],
        "settings": settings,
        "height_bins": [h if math.isfinite(h) else None for h in HEIGHT_BINS],
        "found": found.tolist(),
        "total": total.tolist(),
        "truncated": trunc,
        "edge_err": edge_err,
        "tp_score": tp_score,
        "tp_score_occluded": tp_score_occluded,
        "confusion": confusion.tolist(),
        "fp_boxes": fp_boxes,
        "fp_scores": fp_scores,
        "fp_counts": fp_counts,
        "fp_persist": persist,
        "seconds": elapsed,
    }


def print_stats(stats: dict) -> None:
    """The statistics as tables."""
    edges = [h if h is not None else math.inf for h in stats["height_bins"]]
    names = [
        f"{lo:g}-{hi:g}" if math.isfinite(hi) else f">={lo:g}"
        for lo, hi in zip(edges, edges[1:], strict=False)
    ]
    found, total = np.array(stats["found"]), np.array(stats["total"])
    n = len(stats["frames"])
    print(
        f"\nCNN detection statistics (checkpoint sha256 {stats.get('sha', '?')}, "
        f"{stats['settings']}), {n} validation frames, labelled Cars not truncated:"
    )
    print(
        "| box height [px] | Cars | miss rate | miss occl. 0 / 1 / 2 | edge error median "
        "x1 y1 x2 y2 [px] | edge spread (1.4826 MAD) [px] | TP score median |"
    )
    print("|---|---|---|---|---|---|---|")
    for b, name in enumerate(names):
        t = total[b].sum()
        if not t:
            continue
        miss = 1 - found[b].sum() / t
        occ = " / ".join(
            f"{1 - found[b, o] / total[b, o]:.2f} ({int(total[b, o])})" if total[b, o] else "-"
            for o in range(3)
        )
        e = np.array(stats["edge_err"][b]).reshape(-1, 4)
        med = np.median(e, axis=0) if len(e) else np.full(4, np.nan)
        mad = 1.4826 * np.median(np.abs(e - med), axis=0) if len(e) else np.full(4, np.nan)
        both = stats["tp_score"][b] + stats["tp_score_occluded"][b]
        sc = np.median(both) if both else math.nan
        print(
            f"| {name} | {int(t)} | {miss:.2f} | {occ} | "
            + " ".join(f"{v:+.1f}" for v in med)
            + " | "
            + " ".join(f"{v:.1f}" for v in mad)
            + f" | {sc:.2f} |"
        )
    occ = [s for ss in stats["tp_score_occluded"] for s in ss]
    clear = [s for ss in stats["tp_score"] for s in ss]
    for name, sc in (("not occluded", np.array(clear)), ("occluded", np.array(occ))):
        if len(sc):
            print(
                f"true-positive scores, {name}: n {len(sc)}, median {np.median(sc):.2f}, "
                f">= 0.7: {np.mean(sc >= 0.7):.2f}, >= 0.9: {np.mean(sc >= 0.9):.2f}"
            )
    tr = stats["truncated"]
    if tr[1]:
        print(f"truncated Cars (> 0.3): {tr[1]}, miss rate {1 - tr[0] / tr[1]:.2f}")
    fs = np.array(stats["fp_scores"])
    print(
        f"false positives: {len(fs)} in {n} frames = {len(fs) / max(n, 1):.2f} per frame; "
        "score quartiles "
        + (" / ".join(f"{q:.2f}" for q in np.percentile(fs, [25, 50, 75])) if len(fs) else "-")
        + "; score histogram (0.3-0.4, ..., 0.9-1.0): "
        + " ".join(str(int(c)) for c in np.histogram(fs, bins=np.arange(0.3, 1.01, 0.1))[0])
    )
    pe = stats["fp_persist"]
    if pe[1]:
        print(
            f"false positives found again in the next frame (IoU >= 0.3, consecutive frames of "
            f"0005): {pe[0]} of {pe[1]} = {pe[0] / pe[1]:.2f}"
        )
    fb = np.array(stats["fp_boxes"]).reshape(-1, 4)
    if len(fb):
        print(
            "false-positive box heights [px] quartiles "
            + " / ".join(f"{q:.0f}" for q in np.percentile(fb[:, 3] - fb[:, 1], [25, 50, 75]))
        )
    c = np.array(stats["confusion"])
    print("orientation confusion (rows: labelled bin 0-3, columns: detected bin 0-3):")
    for r in range(4):
        acc = c[r, r] / c[r].sum() if c[r].sum() else math.nan
        print(f"  bin {r}: " + " ".join(f"{v:4d}" for v in c[r]) + f"  (correct {acc:.2f})")
    print(f"  overall correct {np.trace(c) / max(c.sum(), 1):.2f} of {c.sum()}")
