"""The graph's odometry and TF on real KITTI 0005 (synthetic beside it): its path against the
reference camera poses, the parked cars in odom, and frames without a motion.

Usage: python bench/bench_odometry.py [--no-synthetic] [--bag BAG] [--synthetic-bag BAG]

Runs the demo's graph (player in lockstep, CNN detector, stereo depth with its visual odometry,
tracker with ``tracks_frame: odom``, recorder) on real 0005 (../shared/kitti, 16 frames) and on
the synthetic sequence (100 frames, tiny detector), or reads the given recorded bags, and prints
(eval_node.odometry_check):

- the odometry's step per frame against ORB-SLAM3's (``poses_orbslam3``) and the labelled parked
  cars' (their motion relative to the camera, :func:`label_scale`); the path's largest error in
  % of the distance travelled, against ORB-SLAM3 as it is and rescaled to the labels; on the
  synthetic sequence against the renderer's exact ego motion;
- the position std the odometry reports (nav_msgs/Odometry covariance) against its actual error;
- each parked labelled car's spread in odom (its track's positions) against its length, and the
  track's second difference over the ground beside its labels' taken to odom by the odometry
  (what of a parked car's jitter the odometry's error can explain);
- offline, the same recorded camera motions integrated with every 3rd (and every 2nd) motion
  withheld, as when the odometry fails on a frame: the path error and the reported std.

The load average is printed before and after (the machine may be shared).
"""

from __future__ import annotations

import argparse
import os
import random
import sys
from pathlib import Path

os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(101, 200)))

import numpy as np  # noqa: E402
from vehicle_common.odometry import OdometryIntegrator, Pose  # noqa: E402

from eval_node import odometry_check as oc  # noqa: E402
from tracking_bringup import demo  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
REAL_ROOT = REPO.parent / "shared" / "kitti" / "tracking" / "training"
OUT = REPO / "output" / "bench_odometry"


def loadavg() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def run_graph(out: Path, real: bool) -> Path:
    args = ["--output", str(out), "--no-eval", "-p", "vehicle_tracker.tracks_frame:=odom"]
    if real:
        args += ["--kitti-root", str(REAL_ROOT), "--sequence", "0005"]
    else:
        args += ["--data-dir", str(OUT / "synthetic_data")]
    code = demo.main(args)
    if code != 0:
        sys.exit(f"error: the graph failed (exit {code}); logs in {out / 'logs'}")
    return out / "bag"


def synthetic_reference(frames: int) -> list[Pose]:
    """The synthetic camera's exact poses: straight along the optical axis at the scene's
    ego speed (kitti_player_node.synthetic_scene)."""
    from kitti_player_node.synthetic import build_renderer

    speed = build_renderer("0000", frames).scene.ego_speed
    return [Pose(np.eye(3), [0.0, 0.0, speed * 0.1 * k]) for k in range(frames)]


def withheld(frames: list[oc.OdometryFrame], lost: set[int]):
    """The recorded motions integrated again with the motions of the frames at positions
    ``lost`` withheld (the others as recorded): camera positions and position std per frame."""
    odo = OdometryIntegrator(frames[0].camera_pose)
    pos, std = {}, {}
    for i, f in enumerate(frames):
        motion = None if i in lost else f.motion
        s = odo.update(f.stamp_ns, motion)
        pos[f.frame] = s.pose.translation
        std[f.frame] = float(np.sqrt(np.trace(s.covariance[:3, :3])))
    return pos, std


def report(name: str, frames: list[oc.OdometryFrame], reference: list[Pose], labels: bool) -> None:
    print(f"\n## {name}: {len(frames)} frames")
    first = frames[0].camera_pose
    pos = {f.frame: f.camera_pose.translation for f in frames if f.camera_pose is not None}
    missing = sum(f.motion is None for f in frames[1:])
    print(f"frames whose 3D array carried no camera motion (after the first): {missing}")
    raw = oc.path_agreement(pos, first, reference)
    rows = [("reference poses as they are", raw)]
    scale = 1.0
    if labels:
        scale, pairs = oc.label_scale(oc.label_centres(frames), reference)
        print(
            f"labelled parked cars: the camera steps {scale * raw['step_m']:.3f} m per frame "
            f"({scale:.4f} x the reference's {raw['step_m']:.3f} m; {pairs} frame pairs)"
        )
        rows.append(
            ("reference rescaled to the labels", oc.path_agreement(pos, first, reference, scale))
        )
    print(
        "| reference | distance m | odometry m | step m (odometry / ref) | max error m | "
        "end error m | max error % of distance |"
    )
    print("|---|---|---|---|---|---|---|")
    for label, r in rows:
        print(
            f"| {label} | {r['distance_m']:.2f} | {r['odometry_distance_m']:.2f} | "
            f"{r['odometry_step_m']:.3f} / {r['step_m']:.3f} | {r['max_error_m']:.2f} | "
            f"{r['end_error_m']:.2f} | {r['max_error_pct']:.2f} |"
        )
    last = frames[-1]
    if last.odometry is not None:
        cov = last.odometry[1]
        best = rows[-1][1]
        print(
            f"reported position std at the last frame: {np.sqrt(np.trace(cov[:3, :3])):.3f} m "
            f"(3D), actual error there {best['end_error_m']:.3f} m"
        )
    spreads = oc.parked_car_spreads(frames)
    if spreads:
        print(
            "| parked car (label id) | frames matched | track ids | spread in odom m | "
            "spread x-y m | length m | track's second difference x-y m | its labels' in odom "
            "(the odometry's error + the labels' noise) m |"
        )
        print("|---|---|---|---|---|---|---|---|")
        for c in spreads:
            if c["frames"]:
                print(
                    f"| {c['label']} | {c['frames']} | {c['tracks']} | {c['spread_m']:.2f} | "
                    f"{c['spread_xy_m']:.2f} | {c['length_m']:.2f} | {c['jitter_xy_m']:.3f} | "
                    f"{c['label_jitter_xy_m']:.3f} |"
                )
            else:
                print(f"| {c['label']} | 0 | - | - | - | {c['length_m']:.2f} | - | - |")
    print("odometry failing on frames (offline, the recorded motions integrated again):")
    print(
        "| motions withheld | max error % (reference rescaled) | end error m | "
        "reported std at the end m |"
    )
    print("|---|---|---|---|")
    n = len(frames)
    cases = [
        ("none (the node's integration, replayed)", set()),
        ("every 3rd from frame 2", set(range(2, n, 3))),
        ("every 2nd from frame 2", set(range(2, n, 2))),
        ("frame 1's only (no motion known yet)", {1}),
    ]
    for label, lost in cases:
        p, std = withheld(frames, lost)
        r = oc.path_agreement(p, first, reference, scale)
        print(
            f"| {label} | {r['max_error_pct']:.2f} | {r['end_error_m']:.2f} | "
            f"{std[frames[-1].frame]:.3f} |"
        )
    replay, _ = withheld(frames, set())
    dev = max(np.linalg.norm(replay[k] - pos[k]) for k in pos)
    print(f"offline replay of the integration vs the node's /tf: max {dev:.2e} m apart")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bag", help="a recorded real 0005 run (tracks_frame odom) to analyse")
    ap.add_argument("--synthetic-bag", help="a recorded synthetic run to analyse")
    ap.add_argument("--no-synthetic", action="store_true")
    args = ap.parse_args()
    print(f"load average before: {loadavg()}")
    if not (REAL_ROOT / "poses_orbslam3" / "0005.txt").is_file():
        return (
            print(f"error: {REAL_ROOT}: no real KITTI 0005 with poses_orbslam3", file=sys.stderr)
            or 2
        )
    bag = Path(args.bag) if args.bag else run_graph(OUT / "real", real=True)
    reference = oc.read_reference_poses(REAL_ROOT / "poses_orbslam3" / "0005.txt")
    report("real KITTI 0005 (CNN detector)", oc.read_odometry_run(bag), reference, labels=True)
    if not args.no_synthetic:
        sbag = (
            Path(args.synthetic_bag) if args.synthetic_bag else run_graph(OUT / "synthetic", False)
        )
        frames = oc.read_odometry_run(sbag)
        report("synthetic 0000 (tiny detector)", frames, synthetic_reference(len(frames)), False)
    print(f"\nload average after: {loadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
