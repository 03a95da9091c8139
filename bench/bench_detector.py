"""Benchmark of the 2D vehicle detector: accuracy and CPU inference time.

Prints, for the shipped (or a given) checkpoint:
- on the detector's fixed real reporting split (detector_node.real_split since issue 34: every
  labelled frame in ../shared/kitti of tracking sequences 0001, 0005, 0008 and 0010: tracking
  0001 and 0005, their tracking keyframes and the 11 object frames that are frames of them, 90
  frames; never trained on, no choice made on it), with --parts on each of its three parts, and on a
  held-out synthetic sequence (generated here with a seed not used for training,
  or given with --synthetic ROOT:SEQ): 2D AP at IoU 0.5 and 0.7 (eval_node.detection_metrics:
  KITTI devkit AP_R40 per difficulty, and the detector's own all-boxes VOC AP), orientation
  accuracy over matched detections (IoU >= 0.5) and its 4x4 confusion matrix (rows: true bin,
  columns: predicted bin; bins 0/45/90/135 deg), with the majority-bin baseline and the
  balanced accuracy beside it, and the median error of the continuous observation angle (folded
  modulo 180 deg; the bin centre for checkpoints without the angle head) over the same pairs;
  KITTI AP|R40 per occlusion level 0 / 1 / 2 (hard's height and truncation limits, Cars of the
  other levels ignored), and precision / recall of the detections at the node's score threshold
  0.3 (IoU > 0.5, KITTI hard rules);
- the median inference time (preprocessing + network + decoding) on a 1242x375 frame of the
  checkpoint and of the previous model ``tiny_kitti.pt`` (and with --with-full the paper's full
  configuration) on the 16 left images of real tracking 0005 (a random-noise frame without
  ../shared or with --timing-frames random), runs interleaved in one process, threads = 1 (the
  graph's detector setting),
  the CenterNet on ONNX Runtime when installed (``--runtime``; with --compare-torch on PyTorch
  beside it), 3
  warm-up runs, the ratio to tiny_kitti and the load average before and after;
- with ``--also CHECKPOINT`` (e.g. the previous release's file), the same figures of that
  checkpoint on the same real frames, and its time in the same run, interleaved.

Usage: python bench/bench_detector.py [--checkpoint PT|NAME] [--also PT|NAME] [--threads 1]
       [--synthetic ROOT:SEQ] [--skip-synthetic] [--skip-timing] [--skip-real] [--parts]
       [--runs 20] [--with-full] [--input-width W --input-height H] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from detector_node.checkpoint import SHIPPED_CHECKPOINT, load_checkpoint
from detector_node.inference import CnnDetector
from detector_node.loading import load_detector
from detector_node.model import YoloV2Passthrough, preset
from detector_node.real_split import report_sources
from tracking_bringup.detector_scoring import evaluate
from vehicle_common.kitti import read_png
from vehicle_common.malloc_policy import keep_freed_memory

REPO = Path(__file__).resolve().parent.parent
SHARED_KITTI = REPO.parent / "shared" / "kitti"
HELDOUT_SEED = 1000
#: the previous shipped model, the timing baseline (loaded by name)
BASELINE = SHIPPED_CHECKPOINT.parent / "tiny_kitti.pt"


def timing_frames(kind: str = "real") -> tuple[list[np.ndarray], str]:
    """The frames the timing runs cycle through: the 16 left images of real tracking 0005
    (1242x375) when ``kind`` is 'real' and they are there, else one random-noise 1242x375 frame
    (whose many weak heat-map peaks make the decoding slower than on a real frame)."""
    folder = SHARED_KITTI / "tracking" / "training" / "image_02" / "0005"
    if kind == "real" and folder.is_dir():
        frames = [read_png(f) for f in sorted(folder.glob("*.png"))]
        if frames:
            return frames, f"the {len(frames)} left images of real tracking 0005"
    rgb = np.random.default_rng(0).integers(0, 255, (375, 1242, 3), dtype=np.uint8)
    return [rgb], "a random-noise frame"


def time_models(
    models: dict, runs: int = 20, warmup: int = 3, frames: list[np.ndarray] | None = None
) -> dict[str, float]:
    """Median seconds per 1242x375 frame (preprocessing + network + decoding) of each model,
    the runs interleaved (model A, model B, A, B, ...) so that they share the machine's load;
    run i uses frame i of ``frames`` (cycled; default a random-noise frame)."""
    dets = {
        k: m if hasattr(m, "detect") else CnnDetector(m, "cpu", score_threshold=0.3)
        for k, m in models.items()
    }
    frames = frames or timing_frames("random")[0]
    for i in range(warmup):
        for det in dets.values():
            det.detect(frames[i % len(frames)])
    times: dict[str, list[float]] = {k: [] for k in dets}
    for i in range(runs):
        rgb = frames[i % len(frames)]
        for k, det in dets.items():
            t0 = time.perf_counter()
            det.detect(rgb)
            times[k].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in times.items()}


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--checkpoint", default="", help="detector checkpoint ('' = shipped)")
    p.add_argument(
        "--also",
        default="",
        help="a second checkpoint (file or name, e.g. the previous release's) scored on the same "
        "real frames and timed in the same run, its runs interleaved with the checkpoint's",
    )
    p.add_argument("--synthetic", help="held-out synthetic data ROOT:SEQ (default: generate)")
    p.add_argument("--frames", type=int, default=100, help="frames of the generated sequence")
    p.add_argument(
        "--threads", type=int, default=1, help="torch / ONNX Runtime threads (graph setting: 1)"
    )
    p.add_argument(
        "--runtime",
        default="auto",
        choices=("auto", "torch", "onnxruntime"),
        help="runtime of the checkpoint (auto: ONNX Runtime for CenterNet when installed)",
    )
    p.add_argument("--score-threshold", type=float, default=0.05)
    p.add_argument("--skip-timing", action="store_true")
    p.add_argument("--skip-synthetic", action="store_true", help="real reporting frames only")
    p.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    p.add_argument("--parts", action="store_true", help="also each part of the reporting split")
    p.add_argument("--skip-real", action="store_true", help="no real-data evaluation")
    p.add_argument("--input-width", type=int, default=0, help="override (0 = checkpoint's)")
    p.add_argument("--input-height", type=int, default=0, help="override (0 = checkpoint's)")
    p.add_argument("--runs", type=int, default=20, help="timed runs per model")
    p.add_argument(
        "--compare-torch",
        action="store_true",
        help="also time the checkpoint on PyTorch (interleaved: its 100 ms runs slow the others "
        "down by a millisecond or two, through the caches)",
    )
    p.add_argument(
        "--timing-frames",
        choices=("real", "random"),
        default="real",
        help="time on real 0005 frames (when ../shared/kitti is there) or a random-noise frame",
    )
    p.add_argument(
        "--with-full", action="store_true", help="also time the paper's full configuration"
    )
    p.add_argument(
        "--glibc-malloc",
        action="store_true",
        help="time with glibc's malloc defaults (default: the nodes' keep_freed_memory policy)",
    )
    return p


def _load_detectors(args) -> dict:
    """{"": the checkpoint's detector, "also": ``--also``'s when given}, each described."""
    det = load_detector(
        args.checkpoint,
        "cpu",
        score_threshold=args.score_threshold,
        input_width=args.input_width,
        input_height=args.input_height,
        runtime=args.runtime,
    )
    dets = {"": det}
    if args.also:
        dets["also"] = load_detector(
            args.also, "cpu", score_threshold=args.score_threshold, runtime=args.runtime
        )
    for key, d in dets.items():
        c = d.config
        print(
            f"{key or 'checkpoint'}: {(args.also if key else args.checkpoint) or 'shipped'}: "
            f"{c.size} (width {c.width}, depth {c.depth}), input {c.input_width}x"
            f"{c.input_height}, runtime {d.runtime}, threads {args.threads}"
        )
    return dets


def _evaluate_real(args, dets: dict, results: dict) -> None:
    """AP of each detector on the real reporting split (and its parts with ``--parts``)."""
    if not (SHARED_KITTI / "README.md").is_file():
        print(f"\n(real KITTI frames not found at {SHARED_KITTI}; skipped)")
        return
    val = report_sources(SHARED_KITTI)
    for pre, d in dets.items():
        tag = f"[{args.also}] " if pre else ""
        results[f"{pre}real_val"] = evaluate(
            d,
            val,
            f"{tag}real reporting split (every frame here of sequences 0001, 0005, 0008, "
            "0010: tracking, keyframes, object frames)",
        )
        if args.parts:
            for key, spec in zip(("tracking", "keyframes", "object"), val, strict=True):
                label = f"{tag}reporting part: {key}"
                results[f"{pre}real_val_{key}"] = evaluate(d, [spec], label)


def _evaluate_synthetic(args, det, results: dict) -> None:
    """AP of the checkpoint on held-out synthetic data (``--synthetic`` or generated)."""
    with tempfile.TemporaryDirectory() as tmp:
        spec = args.synthetic
        if not spec:
            from kitti_player_node.synthetic import generate_sequence

            generate_sequence(Path(tmp), "0100", args.frames, HELDOUT_SEED)
            spec = f"{tmp}:0100"
        label = f"held-out synthetic (seed {HELDOUT_SEED})"
        results["synthetic"] = evaluate(det, [spec], label)


def _time_detectors(args, dets: dict, results: dict) -> None:
    """Inference time per frame of the checkpoint, ``--also``'s, the torch runtime's
    (``--compare-torch``), the tiny_kitti baseline and the full configuration (``--with-full``),
    runs interleaved; the ratios in one run."""
    det = dets[""]
    frames, what = timing_frames(args.timing_frames)
    print(
        f"\n== inference time per 1242x375 frame (median of {args.runs}, runs interleaved, "
        f"threads {args.threads}, on {what}); load average before: "
        f"{' '.join(f'{v:.2f}' for v in os.getloadavg())}"
    )
    models = {f"checkpoint ({det.runtime})": det}
    if args.also:
        models[f"also {args.also} ({dets['also'].runtime})"] = dets["also"]
    if det.runtime != "torch" and args.compare_torch:
        models["checkpoint (torch)"] = load_detector(
            args.checkpoint,
            "cpu",
            0.3,
            input_width=args.input_width,
            input_height=args.input_height,
            runtime="torch",
        )
    base, _ = load_checkpoint(BASELINE, "cpu")
    models["baseline tiny_kitti"] = base
    if args.with_full:
        models["full (1152x352, random weights)"] = YoloV2Passthrough(preset("full")).eval()
    t = time_models(models, runs=args.runs, frames=frames)
    t["checkpoint"] = t[f"checkpoint ({det.runtime})"]
    for k, v in t.items():
        if k == "checkpoint":
            continue
        print(f"  {k:34s} {1000 * v:7.1f} ms  {1 / v:5.1f} fps")
    ratio = t["checkpoint"] / t["baseline tiny_kitti"]
    print(f"  checkpoint / tiny_kitti time ratio: {ratio:.2f} (same run)")
    if args.also:
        also = t[f"also {args.also} ({dets['also'].runtime})"]
        results["timing_ratio_to_also"] = t["checkpoint"] / also
        print(f"  checkpoint / {args.also} time ratio: {t['checkpoint'] / also:.2f} (same run)")
    print(f"  load average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    results["timing_s"] = t
    results["timing_ratio_to_tiny_kitti"] = ratio


def main() -> None:
    args = _parser().parse_args()
    if not args.glibc_malloc:
        keep_freed_memory()  # as the detector node runs (its keep_freed_memory parameter)
    torch.set_num_threads(args.threads)
    dets = _load_detectors(args)
    results = {}
    if not args.skip_real:
        _evaluate_real(args, dets, results)
    if not args.skip_synthetic:
        _evaluate_synthetic(args, dets[""], results)
    if not args.skip_timing:
        _time_detectors(args, dets, results)
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
