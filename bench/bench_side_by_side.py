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


def _paths(stages, seq, pairs):
    """The two frame paths, ``path(frame, left, right)`` -> the stereo pipeline's result:
    today's (CNN, then the pipeline in the boxes) and side by side (the band's map in a second
    thread while the CNN runs, then the pipeline's ranging on it)."""
    from stereo_depth_node.disparity import compute_disparity
    from stereo_depth_node.offline import FRAME_NS
    from stereo_depth_node.pipeline import FrameBoxes

    detector = stages.detector
    boxes_path, band_path = stages.pipeline(), stages.pipeline(map_area="band")
    for pipeline in (boxes_path, band_path):
        pipeline.camera_from_projections(pairs[0][0], seq.calib.P2, seq.calib.P3)
    geometry, settings = boxes_path.camera()
    params = boxes_path.disparity_params_for(pairs[0][0].shape[0], settings)
    side = ThreadPoolExecutor(1, thread_name_prefix="side")
    for _ in range(3):  # warm-up
        detector.detect(pairs[0][0])
        compute_disparity(*pairs[0], params)

    def today(k, left, right):
        boxes = FrameBoxes.from_detections(detector.detect(left))
        out = boxes_path.process(k * FRAME_NS, left, right, geometry, params, boxes)
        boxes_path.frame_done(boxes.boxes)
        return out

    def side_by_side(k, left, right):
        disparity = side.submit(compute_disparity, left, right, params)  # beside the CNN
        boxes = FrameBoxes.from_detections(detector.detect(left))
        out = band_path.process(
            k * FRAME_NS, left, right, geometry, params, boxes, disparity=disparity.result()
        )
        band_path.frame_done(boxes.boxes)
        return out

    return {"today": today, "side by side": side_by_side}


def _time_paths(paths, frames, pairs, repeats):
    """Both paths on every frame, alternated: (per path, latency and CPU ms per frame), the
    distances [m] between the two paths' 3D positions of the same box."""
    figures: dict[str, dict[str, list[float]]] = {name: {} for name in paths}
    apart: list[float] = []
    for _ in range(repeats):
        for k, (left, right) in enumerate(pairs):
            results = {}
            for name, path in paths.items():
                t0, c0 = time.perf_counter(), time.process_time()
                results[name] = path(frames[k], left, right)
                f = figures[name]
                f.setdefault("latency ms", []).append(1e3 * (time.perf_counter() - t0))
                f.setdefault("CPU ms", []).append(1e3 * (time.process_time() - c0))
            a, b = ({i: r.position for i, r, _, _ in results[n].kept} for n in results)
            apart += [float(np.linalg.norm(a[i] - b[i])) for i in a if i in b]
    return figures, apart


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=3, help="passes over the frames")
    parser.add_argument("--json", help="write the figures to this file")
    args = parser.parse_args(argv)
    if not (REAL_ROOT / "image_02" / "0005").is_dir():
        print(f"error: {REAL_ROOT}: no KITTI 0005 (../shared/kitti)", file=sys.stderr)
        return 2
    from tracking_bringup.offline_stages import graph_stages
    from vehicle_common.kitti import TrackingSequence

    load0 = os.getloadavg()[0]
    seq = TrackingSequence.open(REAL_ROOT, "0005")
    frames = seq.frame_ids[: args.frames]
    pairs = [seq.read_stereo(f) for f in frames]
    stages = graph_stages()
    figures, apart = _time_paths(_paths(stages, seq, pairs), frames, pairs, args.repeats)
    load1 = os.getloadavg()[0]
    summary = {
        name: {key: statistics.median(v) for key, v in f.items()} for name, f in figures.items()
    }
    t, s = summary["today"], summary["side by side"]
    print(
        f"real 0005, {len(pairs)} frames x {args.repeats}, CNN {stages.detector_threads} "
        f"threads, OpenCV {stages.stereo_config.node.num_threads} threads, load {load0:.1f} -> "
        f"{load1:.1f} ({os.cpu_count()} CPUs here)"
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
