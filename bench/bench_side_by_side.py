"""Issue #39: is running the detector and the stereo matching of the same frame side by side,
on two cores, the better pipeline?

    python bench/bench_side_by_side.py [--frames 16] [--repeats 3] [--json FILE]

Today's path (the graph's, in order): the CNN on the left image, then the stereo node's frame
with those boxes (``map_area: boxes``: the scene's block matching, the disparity map in the
boxes, the road plane's and the odometry's work in its helper thread, the ranging and check).
Side by side: the disparity map of the whole band (``map_area: band``, the only map that does
not need the boxes) computed in a second thread WHILE the CNN runs, then the ranging and check
of the boxes on it (the stereo node's ``map_area: band`` path, the map given). Both paths run
here, alternated frame by frame over real KITTI 0005 (``../shared/kitti``), with the graph's
thread counts (``pipeline.params.yaml``); the figures are per frame, median:

- latency: image in -> 3D detections out (wall), each path;
- CPU: process CPU time per frame (every thread), each path;
- and the load average before / after (speed figures are ratios of this run).

Both paths give their 3D detections; the bench prints how far apart they are (the band's map
and the boxes' map are the same algorithm on the same rows, so positions should agree).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
REAL_ROOT = REPO.parent / "shared" / "kitti" / "tracking" / "training"


def _boxes(dets):
    from stereo_depth_node.pipeline import FrameBoxes

    return FrameBoxes(
        [d.box for d in dets],
        [d.orientation_bin for d in dets],
        [d.observation_angle for d in dets],
        [d.observation_angle_variance for d in dets],
        [d.score for d in dets],
        [str(i) for i in range(len(dets))],
    )


def _graph_setup(overrides: dict):
    """The detector and the stereo pipeline as the graph's nodes run them (thread counts and
    the ``stereo_depth`` section of the graph's parameter file, ``overrides`` on top)."""
    import cv2
    import torch
    from detector_node.loading import load_detector
    from stereo_depth_node.parameters import stereo_config_from_values
    from stereo_depth_node.pipeline import StereoPipeline
    from tracking_bringup.environment import PARAMS_FILE

    from tracking_bringup import graph

    values = dict(graph.file_parameters(PARAMS_FILE).get(graph.STEREO.name, {}))
    values.update(overrides)
    config = stereo_config_from_values(values)
    det_threads = int(graph.parameter_value(PARAMS_FILE, [], graph.DETECTOR.name, "num_threads"))
    torch.set_num_threads(det_threads)
    cv2.setNumThreads(config.node.num_threads)
    return load_detector("", "cpu"), StereoPipeline.from_config(config), det_threads, config


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=3, help="passes over the frames")
    parser.add_argument("--json", help="write the figures to this file")
    args = parser.parse_args(argv)
    if not (REAL_ROOT / "image_02" / "0005").is_dir():
        print(f"error: {REAL_ROOT}: no KITTI 0005 (../shared/kitti)", file=sys.stderr)
        return 2
    from stereo_depth_node.disparity import compute_disparity
    from stereo_depth_node.offline import FRAME_NS
    from vehicle_common.kitti import TrackingSequence

    load0 = os.getloadavg()[0]
    seq = TrackingSequence.open(REAL_ROOT, "0005")
    frames = seq.frame_ids[: args.frames]
    pairs = [seq.read_stereo(f) for f in frames]
    detector, boxes_path, det_threads, config = _graph_setup({})
    _, band_path, _, _ = _graph_setup({"map_area": "band"})
    for pipeline in (boxes_path, band_path):
        pipeline.camera_from_projections(pairs[0][0], seq.calib.P2, seq.calib.P3)
    geometry, settings = boxes_path.camera()
    params = boxes_path.disparity_params_for(pairs[0][0].shape[0], settings)
    side = ThreadPoolExecutor(1, thread_name_prefix="side")
    for _ in range(3):  # warm-up
        detector.detect(pairs[0][0])
        compute_disparity(*pairs[0], params)

    def today(k, left, right):
        boxes = _boxes(detector.detect(left))
        out = boxes_path.process(k * FRAME_NS, left, right, geometry, params, boxes)
        boxes_path.frame_done(boxes.boxes)
        return out

    def side_by_side(k, left, right):
        disparity = side.submit(compute_disparity, left, right, params)  # beside the CNN
        boxes = _boxes(detector.detect(left))
        out = band_path.process(
            k * FRAME_NS, left, right, geometry, params, boxes, disparity=disparity.result()
        )
        band_path.frame_done(boxes.boxes)
        return out

    figures: dict[str, dict[str, list[float]]] = {"today": {}, "side by side": {}}
    apart: list[float] = []
    for _ in range(args.repeats):
        for k, (left, right) in enumerate(pairs):
            results = {}
            for name, path in (("today", today), ("side by side", side_by_side)):
                t0, c0 = time.perf_counter(), time.process_time()
                results[name] = path(frames[k], left, right)
                f = figures[name]
                f.setdefault("latency ms", []).append(1e3 * (time.perf_counter() - t0))
                f.setdefault("CPU ms", []).append(1e3 * (time.process_time() - c0))
            a, b = ({i: r.position for i, r, _, _ in results[n].kept} for n in results)
            apart += [float(np.linalg.norm(a[i] - b[i])) for i in a if i in b]
    side.shutdown()
    load1 = os.getloadavg()[0]
    summary = {
        name: {key: statistics.median(v) for key, v in f.items()} for name, f in figures.items()
    }
    t, s = summary["today"], summary["side by side"]
    print(
        f"real 0005, {len(pairs)} frames x {args.repeats}, CNN {det_threads} threads, OpenCV "
        f"{config.node.num_threads} threads, load {load0:.1f} -> {load1:.1f} (2 cores: "
        f"{os.cpu_count()} CPUs here)"
    )
    for name, f in summary.items():
        print(
            f"  {name:13s} latency {f['latency ms']:6.1f} ms, CPU {f['CPU ms']:6.1f} ms per frame"
        )
    print(
        f"  side by side / today: latency {s['latency ms'] / t['latency ms']:.2f}x, CPU "
        f"{s['CPU ms'] / t['CPU ms']:.2f}x; 3D positions apart: median "
        f"{statistics.median(apart) if apart else float('nan'):.2f} m over {len(apart)} cars"
    )
    if args.json:
        Path(args.json).write_text(json.dumps({**summary, "load": [load0, load1]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
