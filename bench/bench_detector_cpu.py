"""Where the detector's CPU goes, and what its runtime levers save (issue #39 item 3).

On the real left frames of ../shared (tracking 0005's 16, then 0001's first 14: 30 frames) and
the shipped checkpoint at its 896x224 framing, in ONE process, runs interleaved frame by frame:
- the CPU (``time.process_time``: every thread of the process) and wall time per frame of the
  node's ONNX Runtime session at 1 and 2 intra-op threads, and of variants of its session
  options (``--variants``), each as a ratio to the shipped session (1 thread, the graph's
  setting);
- the detector's whole ``detect`` split into preprocessing (crop + resize), ``Session.run``
  and decoding (peaks, orientation head, NMS);
- with ``--profile``, ONNX Runtime's own profile of the shipped session: time per node type;
- with ``--int8 N``, a static INT8 (QDQ, per-channel) copy of the graph calibrated on N
  frames of the project's synthetic renderer (what a fresh clone has), timed beside the
  others, with the agreement of its detections with the float graph's on the real frames
  (``--int8-reduce-range``: 7-bit weights; ``--int8-calibration real``: a diagnostic);
- with ``--sizes WxH[@ROI],...``, the whole ``detect`` at other framings, timed beside the
  shipped one, and with ``--tune`` their AP on issue 34's training (tuning) frames.
OpenBLAS runs on one thread and freed memory is kept, as in the node. The fixed reference
workload (../shared/tools/cpu_reference.py) and the load average are printed before and after.

Usage: python bench/bench_detector_cpu.py [--frames 30] [--profile] [--variants] [--rounds 1]
       [--int8 20 [--int8-reduce-range] [--int8-calibration synthetic|real]]
       [--sizes 768x224,896x192@0.3 [--tune]]   (--rounds 0: no timing)
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
TRACKING = SHARED / "kitti" / "tracking" / "training" / "image_02"


def load_frames(n: int) -> list[np.ndarray]:
    import cv2

    paths = sorted((TRACKING / "0005").glob("*.png")) + sorted((TRACKING / "0001").glob("*.png"))
    if not paths:
        sys.exit(f"error: {TRACKING}: no real frames (../shared is needed)")
    return [cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB) for p in paths[:n]]


def reference_ms() -> str:
    tool = SHARED / "tools" / "cpu_reference.py"
    if not tool.is_file():
        return "n/a"
    out = subprocess.run([sys.executable, str(tool)], capture_output=True, text=True, cwd=ROOT)
    return out.stdout.strip() or "n/a"


def loadavg() -> str:
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "n/a"


def session(graph: bytes, threads: int, **options):
    """The node's session (``onnx_session.ort_session``) or a variant of its options."""
    from detector_node.onnx_session import ort_session

    return ort_session(graph, threads, **options)


def synthetic_frames(n: int) -> list[np.ndarray]:
    from kitti_player_node.synthetic import build_renderer, render_stereo_frame

    renderer = build_renderer("0099", frames=max(n, 2), seed=7)
    return [render_stereo_frame(renderer, k, "0099")[0] for k in range(n)]


def training_frames(n: int) -> list[np.ndarray]:
    from detector_node.dataset import frames_from_source, read_png
    from detector_node.real_split import train_sources

    refs = [r for spec in train_sources(SHARED / "kitti") for r in frames_from_source(spec)]
    step = max(1, len(refs) // n)
    return [read_png(r.image_path) for r in refs[::step][:n]]


def profile(graph: bytes, inputs: list[np.ndarray]) -> None:
    import onnxruntime as ort

    with tempfile.TemporaryDirectory() as tmp:
        sess = session(graph, 1, profile_prefix=os.path.join(tmp, "ort"))
        for x in inputs:
            sess.run(None, {"image": x})
        path = sess.end_profiling()
        events = json.loads(Path(path).read_text())
    per = collections.defaultdict(float)
    nodes = collections.defaultdict(float)
    total = 0.0
    for e in events:
        if e.get("cat") == "Node" and e["name"].endswith("_kernel_time"):
            per[e["args"]["op_name"]] += e["dur"]
            nodes[e["name"][: -len("_kernel_time")]] += e["dur"]
            total += e["dur"]
    print(f"ONNX Runtime profile (1 thread, {len(inputs)} frames, ort {ort.__version__}):")
    for op, us in sorted(per.items(), key=lambda kv: -kv[1]):
        print(f"  {op:22s} {us / len(inputs) / 1000:6.2f} ms/frame  {100 * us / total:5.1f} %")
    print(f"  {'all nodes':22s} {total / len(inputs) / 1000:6.2f} ms/frame")
    top = sorted(nodes.items(), key=lambda kv: -kv[1])
    head = sum(us for name, us in nodes.items() if "Head" in name or "head" in name)
    print(f"  nodes named *head* (the CenterNet head at stride 4): {100 * head / total:.1f} %")
    for name, us in top[:8]:
        print(f"  {100 * us / total:5.1f} %  {name}")


def time_variants(calls: dict, n: int, rounds: int) -> dict:
    """{name: (CPU ms, wall ms) per call} of callables ``f(i)`` over frames 0..n-1, interleaved
    frame by frame (each warmed up on 3 frames first)."""
    cpu = {k: [] for k in calls}
    wall = {k: [] for k in calls}
    for f in calls.values():
        for i in range(3):
            f(i)
    for _ in range(rounds):
        for i in range(n):
            for name, f in calls.items():
                c0, w0 = time.process_time(), time.perf_counter()
                f(i)
                cpu[name].append(time.process_time() - c0)
                wall[name].append(time.perf_counter() - w0)
    return {k: (1000 * np.mean(cpu[k]), 1000 * np.mean(wall[k])) for k in calls}


def print_ratios(title: str, res: dict) -> None:
    base = next(iter(res))
    base_cpu, base_wall = res[base]
    print(title)
    print(f"  {'variant':28s} {'CPU ms':>7s} {'ratio':>6s} {'wall ms':>8s} {'ratio':>6s}")
    for name, (cpu, wall) in res.items():
        print(f"  {name:28s} {cpu:7.1f} {cpu / base_cpu:6.2f} {wall:8.1f} {wall / base_wall:6.2f}")


def split_detect(det, frames: list[np.ndarray]) -> None:
    """Preprocessing, Session.run and decoding of the node's detect, CPU ms per frame."""
    from detector_node import onnx_detector as od

    parts = collections.defaultdict(float)
    real_run = od.OnnxCenterNetDetector.session
    timed = {}

    def wrapped(self, h, w):
        s = real_run(self, h, w)

        class Timed:
            def run(self_inner, *a, **k):
                c0 = time.process_time()
                out = s.run(*a, **k)
                timed["run"] = time.process_time() - c0
                return out

        return Timed()

    for f in frames[:3]:
        det.detect(f)
    od.OnnxCenterNetDetector.session = wrapped
    try:
        for f in frames:
            c0 = time.process_time()
            det.detect(f)
            total = time.process_time() - c0
            parts["Session.run"] += timed["run"]
            parts["rest (crop + resize + decode)"] += total - timed["run"]
            parts["detect"] += total
    finally:
        od.OnnxCenterNetDetector.session = real_run
    n = len(frames)
    print("detect() of the node's core, 1 thread, CPU ms per frame:")
    for k, v in parts.items():
        print(f"  {k:32s} {1000 * v / n:6.2f}  ({100 * v / parts['detect']:5.1f} %)")


def resize_threads(frames, top: int, width: int, height: int) -> None:
    """CPU of the preprocessing's resize (INTER_AREA) with OpenCV's default threads and one."""
    import cv2
    from detector_node.dataset import resize_image

    default = cv2.getNumThreads()
    out = {}
    for n in (default, 1, default, 1):
        cv2.setNumThreads(n)
        c0 = time.process_time()
        for f in frames:
            resize_image(f[top:], width, height)
        out.setdefault(n, []).append(1000 * (time.process_time() - c0) / len(frames))
    cv2.setNumThreads(default)
    cells = ", ".join(f"{n} thread(s) {np.mean(v):.2f} ms" for n, v in out.items())
    print(f"resize (crop + INTER_AREA) CPU per frame: {cells}")


def quantized(graph: bytes, calib: list[np.ndarray], reduce_range: bool = False) -> bytes:
    """Static INT8 QDQ, per-channel weights, MinMax calibration on ``calib``; ``reduce_range``:
    7-bit weights (AVX2 without VNNI saturates 8-bit products in u8s8 dot products)."""
    import onnx
    from onnxruntime.quantization import (
        CalibrationDataReader,
        QuantFormat,
        QuantType,
        quantize_static,
    )
    from onnxruntime.quantization.shape_inference import quant_pre_process

    class Reader(CalibrationDataReader):
        def __init__(self):
            self.it = iter(calib)

        def get_next(self):
            x = next(self.it, None)
            return None if x is None else {"image": x}

    with tempfile.TemporaryDirectory() as tmp:
        f32, pre, q8 = (os.path.join(tmp, n) for n in ("f.onnx", "p.onnx", "q.onnx"))
        Path(f32).write_bytes(graph)
        quant_pre_process(f32, pre, skip_symbolic_shape=True)
        quantize_static(
            pre,
            q8,
            Reader(),
            quant_format=QuantFormat.QDQ,
            per_channel=True,
            reduce_range=reduce_range,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
            op_types_to_quantize=["Conv"],
        )
        return onnx.load(q8).SerializeToString()


def agreement(det, other, frames) -> None:
    """How far ``other``'s detections (score >= 0.3) are from ``det``'s on the real frames."""
    from vehicle_common.box2d import iou_2d

    ious, n_a, n_b = [], 0, 0
    for f in frames:
        a, b = det.detect(f), other.detect(f)
        n_a, n_b = n_a + len(a), n_b + len(b)
        if a:
            m = iou_2d([d.box for d in a], [d.box for d in b]) if b else np.zeros((len(a), 1))
            ious.extend(m.max(axis=1))
    ious = np.array(ious)
    print(
        f"INT8 vs float detections (score >= 0.3): {n_b} vs {n_a}; IoU of each float box with "
        f"its best INT8 box: median {np.median(ious):.3f}, >= 0.7: {np.mean(ious >= 0.7):.1%}"
    )


def tune(dets: dict) -> None:
    """AP|R40 moderate @0.7 / @0.5, 4-bin orientation and precision at 0.3 of each framing on
    the training frames (full frames with complete labels)."""
    import contextlib
    import io

    from detector_node.real_split import train_sources
    from tracking_bringup.detector_scoring import evaluate

    specs = train_sources(SHARED / "kitti")
    rows = {}
    for name, d in dets.items():
        with contextlib.redirect_stdout(io.StringIO()):
            r = evaluate(d, specs, name)
        ap = r["kitti_ap_r40"]["moderate"]
        op = r["at_node_threshold"]
        rows[name] = (
            100 * ap["0.7"],
            100 * ap["0.5"],
            100 * r["orientation_accuracy"],
            100 * op["precision"],
        )
    base = next(iter(rows.values()))
    print(
        f"tuning frames ({r['frames']} training frames): AP@0.7 mod, AP@0.5 mod, orientation, "
        "precision at 0.3 (difference to the shipped framing)"
    )
    for name, row in rows.items():
        cells = ", ".join(f"{v:5.1f} ({v - b:+5.2f})" for v, b in zip(row, base, strict=True))
        print(f"  {name:22s} {cells}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--rounds", type=int, default=1)
    p.add_argument("--profile", action="store_true")
    p.add_argument("--int8", type=int, default=0, help="calibration frames (0 = no INT8)")
    p.add_argument(
        "--int8-calibration",
        choices=("synthetic", "real"),
        default="synthetic",
        help="synthetic: the project's renderer (what a fresh clone has); real: N evenly spaced "
        "training frames of issue 34's split (a diagnostic: real frames cannot be shipped)",
    )
    p.add_argument("--int8-reduce-range", action="store_true", help="7-bit weights")
    p.add_argument("--variants", action="store_true", help="session-option variants")
    p.add_argument(
        "--tune",
        action="store_true",
        help="score the shipped framing and each --sizes one on the training frames of issue "
        "34's split (the tuning frames; the reporting split is bench_detector.py's)",
    )
    p.add_argument(
        "--sizes",
        default="",
        help="network inputs WxH[@ROI_TOP],... whose whole detect() is timed beside the shipped",
    )
    args = p.parse_args(argv)

    from detector_node.dataset import resize_image
    from detector_node.loading import checkpoint_path, load_detector
    from vehicle_common.blas_threads import set_blas_threads
    from vehicle_common.malloc_policy import keep_freed_memory

    set_blas_threads(1)  # as every node (vehicle_common.node_runtime)
    keep_freed_memory()

    print(f"load {loadavg()}; reference {reference_ms()} ms")
    frames = load_frames(args.frames)
    det = load_detector("", "cpu", 0.3, 0.45, runtime="onnxruntime", threads=1)
    c = det.config
    top = int(round(det.roi_top * frames[0].shape[0]))
    inputs = [
        np.ascontiguousarray(resize_image(f[top:], c.input_width, c.input_height)[0])[None]
        for f in frames
    ]
    graph = det.source.onnx_graph(c.input_height, c.input_width)
    print(
        f"checkpoint {checkpoint_path('')}, input {c.input_width}x{c.input_height}, "
        f"roi_top {det.roi_top}, {len(frames)} real frames"
    )
    if args.profile:
        profile(graph, inputs)
    split_detect(det, frames)
    resize_threads(frames, top, c.input_width, c.input_height)

    import onnxruntime as ort

    sessions = {"shipped (1 thread)": session(graph, 1), "2 threads": session(graph, 2)}
    if args.variants:
        opt = ort.GraphOptimizationLevel
        sessions["opt EXTENDED"] = session(graph, 1, level=opt.ORT_ENABLE_EXTENDED)
        sessions["opt BASIC"] = session(graph, 1, level=opt.ORT_ENABLE_BASIC)
        sessions["no mem pattern"] = session(graph, 1, mem_pattern=False)
        sessions["no cpu arena"] = session(graph, 1, arena=False)
        sessions["denormal as zero"] = session(
            graph, 1, entries={"session.set_denormal_as_zero": "1"}
        )
        sessions["2 thr, spinning"] = session(
            graph, 2, entries={"session.intra_op.allow_spinning": "1"}
        )
    if args.int8:
        if args.int8_calibration == "real":
            calib = training_frames(args.int8)
        else:
            calib = synthetic_frames(args.int8)
        cin = [
            np.ascontiguousarray(resize_image(f[top:], c.input_width, c.input_height)[0])[None]
            for f in calib
        ]
        c0 = time.process_time()
        q = quantized(graph, cin, args.int8_reduce_range)
        print(f"INT8 graph: {len(q)} bytes, quantized in {time.process_time() - c0:.1f} s CPU")
        sessions["int8 QDQ per-channel"] = session(q, 1)
        q8 = load_detector("", "cpu", 0.3, 0.45, runtime="onnxruntime", threads=1)
        q8._sessions[(c.input_height, c.input_width)] = sessions["int8 QDQ per-channel"]
        agreement(det, q8, frames)
    calls = {k: (lambda i, s=v: s.run(None, {"image": inputs[i]})) for k, v in sessions.items()}
    print(f"load {loadavg()} before timing")
    if args.rounds:
        res = time_variants(calls, len(inputs), args.rounds)
        title = f"Session.run per frame ({len(inputs)} frames x {args.rounds}, interleaved):"
        print_ratios(title, res)
    if args.sizes:
        dets = {"shipped 896x224@0.25": det}
        for spec in args.sizes.split(","):
            size, _, roi = spec.partition("@")
            w, h = (int(v) for v in size.split("x"))
            d = load_detector("", "cpu", 0.3, 0.45, runtime="onnxruntime", threads=1)
            d.set_framing(w, h, float(roi) if roi else None)
            dets[f"{w}x{h}@{d.roi_top:g}"] = d
        calls = {k: (lambda i, d=d: d.detect(frames[i])) for k, d in dets.items()}
        if args.rounds:
            res = time_variants(calls, len(frames), args.rounds)
            print_ratios("detect() per frame, 1 thread, by input size:", res)
    if args.tune:
        tune(dets)
    print(f"load {loadavg()}; reference {reference_ms()} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
