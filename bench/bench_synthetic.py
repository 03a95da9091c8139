"""Benchmark of the synthetic KITTI generator: render time of a sequence and label statistics.

Renders one sequence (default 100 frames, 1242x375, seed 0) into a temporary folder, and as a
baseline in the same run writes the same 200 PNGs again without rendering (the PNG-encoding
floor). Prints wall and CPU seconds, the ratio to the baseline, and what the labels contain
(objects per frame, occlusion and truncation, orientation bins, depth range).

    python bench/bench_synthetic.py [--frames 100] [--seed 0]
"""

from __future__ import annotations

import argparse
import collections
import math
import tempfile
import time
from pathlib import Path

from kitti_player_node.synthetic import generate_sequence
from vehicle_common.kitti import TrackingSequence, write_png


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--vehicles", type=int, default=12)
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "synth"
        w0, c0 = time.perf_counter(), time.process_time()
        generate_sequence(root, "0000", args.frames, args.seed, args.vehicles, force=True)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        seq = TrackingSequence.open(root, "0000")
        images = [seq.read_stereo(k) for k in seq.frame_ids]
        w0, c0 = time.perf_counter(), time.process_time()
        for k, (left, right) in enumerate(images):
            write_png(Path(tmp) / "io" / f"{k}_l.png", left)
            write_png(Path(tmp) / "io" / f"{k}_r.png", right)
        io_wall, io_cpu = time.perf_counter() - w0, time.process_time() - c0
        size_mb = sum(f.stat().st_size for f in root.rglob("*.png")) / 1e6
        print(
            f"sequence: {args.frames} frames ({2 * args.frames} images 1242x375), seed {args.seed}"
        )
        print(
            f"generate: wall {wall:.1f} s, cpu {cpu:.1f} s "
            f"({1000 * cpu / args.frames:.0f} ms/frame)"
        )
        print(f"baseline (PNG writes only): wall {io_wall:.1f} s, cpu {io_cpu:.1f} s")
        print(
            f"ratio generate/baseline (cpu): {cpu / max(io_cpu, 1e-9):.1f}x; PNGs {size_mb:.0f} MB"
        )
        stats(seq)
        sgbm_check(args.seed, args.frames, args.vehicles)


def sgbm_check(seed: int, frames: int, vehicles: int) -> None:
    """D1 error (KITTI 2015 rule) of OpenCV SGBM against the rendered true disparity."""
    import cv2
    import numpy as np
    from kitti_player_node.synthetic import build_renderer, render_stereo_frame

    r = build_renderer(frames=frames, seed=seed, vehicles=vehicles)
    bad_all, n_all, bad_veh, n_veh = 0, 0, 0, 0
    for k in range(0, frames, max(frames // 3, 1)):
        truth = r.render(k, 0)
        left, right, _ = render_stereo_frame(r, k)
        sgbm = cv2.StereoSGBM_create(0, 128, 5, P1=200, P2=800, uniquenessRatio=10)
        gray = [cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) for im in (left, right)]
        d = sgbm.compute(*gray).astype(np.float32) / 16.0
        gt = r.calib.fx * r.calib.baseline / truth.depth
        valid = (d > 0) & (gt > 1.0)
        valid[:, :130] = False  # SGBM leaves the left border (max disparity) empty
        err = np.abs(d - gt)
        bad = (err > 3.0) & (err > 0.05 * gt)
        veh = valid & (truth.ids >= 0)
        bad_all, n_all = bad_all + int(bad[valid].sum()), n_all + int(valid.sum())
        bad_veh, n_veh = bad_veh + int(bad[veh].sum()), n_veh + int(veh.sum())
    print(
        f"SGBM on the synthetic pairs: D1 {100 * bad_all / n_all:.1f} % of valid pixels, "
        f"{100 * bad_veh / max(n_veh, 1):.1f} % on vehicles"
    )


def stats(seq: TrackingSequence) -> None:
    n, dontcare = 0, 0
    occ, types, bins = collections.Counter(), collections.Counter(), collections.Counter()
    truncated, depths, tracks = 0, [], set()
    for k in seq.frame_ids:
        for o in seq.objects(k):
            if o.is_dontcare:
                dontcare += 1
                continue
            n += 1
            occ[o.occluded] += 1
            types[o.type] += 1
            truncated += o.truncated > 0
            depths.append(o.location[2])
            tracks.add(o.track_id)
            a = math.degrees(o.alpha) % 180.0
            bins[int(((a + 22.5) % 180.0) // 45.0) * 45] += 1
    frames = len(seq.frame_ids)
    print(f"labels: {n / frames:.1f} objects/frame, {dontcare / frames:.1f} DontCare/frame, ")
    print(f"  tracks {len(tracks)}, types {dict(types)}, occlusion {dict(sorted(occ.items()))}")
    print(f"  truncated {truncated}, depth {min(depths):.1f}..{max(depths):.1f} m")
    print(f"  orientation bins (alpha mod 180, deg): {dict(sorted(bins.items()))}")


if __name__ == "__main__":
    main()
