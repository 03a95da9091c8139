"""The end-to-end demo: data -> whole graph as separate processes -> bag -> evaluation.

1. Renders the project's synthetic KITTI-format sequence (unless it exists), or opens a real
   KITTI tracking root (``--kitti-root DIR --sequence 0005``).
2. Starts the graph (player in lockstep, or as a camera at ``--camera-hz`` Hz; detector, stereo
   depth, tracker, recorder) with the process launcher and shows progress while the sequence
   plays; the last line: frames tracked, dropped and where, latency (``frame_summary``).
3. Evaluates the recorded bag offline (3D localisation mAP, 2D AP, orientation, CLEAR-MOT/HOTA,
   the unfiltered/Kalman/particle comparison), prints the results table and leaves the report,
   figures, logs and bag in one output folder.
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import datetime
from pathlib import Path

from detector_node.loading import checkpoint_path

from tracking_bringup import graph
from tracking_bringup.environment import apply_graph_environment
from tracking_bringup.frame_summary import (
    LatencyProbe,
    camera_overrides,
    dropped_by_node,
    summary_line,
)
from tracking_bringup.launcher import (
    GraphLauncher,
    LaunchError,
    add_params_arguments,
    graph_processes,
    parameter_layers,
)
from tracking_bringup.parameter_file import describe

#: parameters that describe the real KITTI cameras, reset for the synthetic renderer's exact ones
SYNTHETIC_CAMERA_OVERRIDES = (
    "stereo_depth.disparity_bias:=0.0",
    "stereo_depth.disparity_bias_column:=0.0",
    # the default detector (pretrained on COCO, fine-tuned on real KITTI) does not see the
    # renderer's box cars; the previous model was trained on them
    "vehicle_detector.checkpoint:=tiny_kitti",
)


def detector_checkpoint(params_file, user_params: list[str], synthetic: bool) -> str:
    """The checkpoint the demo's detector will load: the parameter file's, then the synthetic
    data's override (``tiny_kitti``), then the user's ``-p vehicle_detector.checkpoint:=``
    (the same order as the overrides the demo passes)."""
    given = [*(SYNTHETIC_CAMERA_OVERRIDES if synthetic else ()), *user_params]
    node_params = graph.node_overrides(given, "vehicle_detector")
    return str(graph.parameter_value(params_file, node_params, "vehicle_detector", "checkpoint"))


def _error(msg: str) -> int:
    print(f"error: {msg}", file=sys.stderr)
    return 2


class TrackProgress:
    """Counts tracked-vehicle arrays (one per processed frame) and shows a progress bar."""

    def __init__(self, total: int):
        from tqdm import tqdm

        self.count = 0
        self._bar = tqdm(
            total=total, unit="frame", desc="pipeline", dynamic_ncols=True, mininterval=0.5
        )
        # each frame's clock and tracks: the latency of the final summary line
        self.probe = LatencyProbe(on_tracks=self._on_tracks)

    def _on_tracks(self, msg) -> None:
        self.count += 1
        self._bar.update(1)
        self._bar.set_postfix(tracks=len(msg.vehicles))

    def close(self) -> None:
        self.probe.close()
        self._bar.close()


def _kitti_settings(checkpoint: str) -> list[str]:
    """KITTI's camera settings as overrides (``--no-camera-settings``: a synthetic camera that
    is not KITTI's run with them instead of the derived ones), printed."""
    from tracking_bringup.camera import KITTI_CAMERA, camera_overrides

    overrides = camera_overrides(KITTI_CAMERA, checkpoint)
    print(f"[demo] KITTI's camera settings instead of the derived ones: {' '.join(overrides)}")
    return overrides


def _prepare_data(args) -> tuple[Path, str, int]:
    """(KITTI tracking root, sequence, number of frames to play)."""
    from vehicle_common.kitti import TrackingSequence

    if args.kitti_root:
        root, sequence = Path(args.kitti_root).resolve(), args.sequence or "0005"
    else:
        from kitti_player_node.synthetic import generate_sequence

        root, sequence = Path(args.data_dir).resolve(), args.sequence or "0000"
        print(f"[demo] synthetic KITTI-format sequence {sequence} in {root}", flush=True)
        t0 = time.monotonic()
        generate_sequence(
            root,
            sequence=sequence,
            frames=args.frames or 100,
            seed=args.seed,
            width=args.width,
            height=args.height,
            focal=args.focal,
            baseline=args.baseline,
        )
        print(f"[demo] data ready ({time.monotonic() - t0:.1f} s)", flush=True)
    seq = TrackingSequence.open(root, sequence)
    n = len(seq.frame_ids) if not args.frames else min(args.frames, len(seq.frame_ids))
    return root, seq.sequence, n


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="stereo_tracking_demo",
        description="Run the whole stereo tracking graph on a sequence and evaluate it.",
    )
    parser.add_argument("--kitti-root", help="KITTI tracking root (holds image_02, calib, ...)")
    parser.add_argument("--sequence", help="sequence name (default 0000 synthetic, 0005 real)")
    parser.add_argument("--frames", type=int, default=0, help="frames to play (0 = all)")
    parser.add_argument("--detector", choices=("cnn", "oracle"), default="cnn")
    parser.add_argument("--data-dir", default="data/synthetic", help="synthetic data folder")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic sequence")
    parser.add_argument("--width", type=int, default=1242, help="synthetic: image width")
    parser.add_argument("--height", type=int, default=375, help="synthetic: image height")
    parser.add_argument(
        "--focal", type=float, default=0.0, help="synthetic: fx = fy [px] (0: KITTI's, scaled)"
    )
    parser.add_argument("--baseline", type=float, default=0.5327, help="synthetic: baseline [m]")
    parser.add_argument(
        "--no-camera-settings",
        action="store_true",
        help="run with KITTI's camera settings (detector input size, region of interest, "
        "num_disparities, match_rows) instead of those the nodes derive from the CameraInfo",
    )
    parser.add_argument("--output", help="output folder (default output/demo_<time>)")
    add_params_arguments(parser)
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NODE.PARAM:=VALUE")
    parser.add_argument("--no-eval", action="store_true", help="skip the offline evaluation")
    parser.add_argument(
        "--camera-hz",
        type=float,
        default=0.0,
        help="play as a camera at this rate, not waiting for the graph (e.g. 30; default: "
        "lockstep, every frame)",
    )
    return parser


def _checked_options(args) -> list[str]:
    """The ``--camera-hz`` overrides; ValueError (its one line) for a bad option or parameter
    file."""
    if args.frames < 0:
        raise ValueError("--frames: must be >= 0")
    problem = parameter_layers(args)  # args.params: the pipeline file, then --params
    if problem:
        raise ValueError(problem)
    camera_rate = camera_overrides(args.camera_hz) if args.camera_hz else []
    graph.file_parameters(args.params)  # one line for a file the launcher cannot use
    return camera_rate


def _camera_settings(args, checkpoint: str) -> list[str]:
    """KITTI's camera settings with ``--no-camera-settings`` (else none: the nodes derive them
    from the CameraInfo); ValueError for a checkpoint that cannot be found, before the graph
    starts (not the node's death)."""
    checkpoint_path(checkpoint)
    return _kitti_settings(checkpoint) if args.no_camera_settings else []


def _graph_overrides(args, root, sequence: str, frames: int, bag: Path, camera: list[str]):
    """The demo's parameter overrides, the user's ``-p`` last."""
    return [
        f"kitti_player.dataset_root:={root}",
        f"kitti_player.sequence:='{sequence}'",
        f"kitti_player.last_frame:={frames - 1}",
        "kitti_player.lockstep:=true",
        "kitti_player.exit_when_done:=true",
        f"vehicle_detector.backend:={args.detector}",
        f"bag_recorder.output:={bag}",
        # the stereo bias model describes KITTI's cameras; the synthetic renderer's are exact
        *([] if args.kitti_root else SYNTHETIC_CAMERA_OVERRIDES),
        *camera,
        *args.param,
    ]


def _run_graph(launcher: GraphLauncher, frames: int) -> tuple[int | None, TrackProgress | None]:
    """Run the graph until the player is done, showing progress: (an exit code when it failed
    or was interrupted, else None; the progress display)."""
    progress = None
    try:
        progress = TrackProgress(frames)  # subscribed before the player publishes anything
        launcher.start()
        launcher.wait(until_finished=True)
    except LaunchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code, progress  # 2: a node refused its parameters or input (its line)
    except KeyboardInterrupt:
        print("[demo] interrupted", file=sys.stderr)
        return 130, progress
    finally:
        launcher.shutdown()  # lets the frames in flight drain first
        if progress is not None:
            progress.close()
    return None, progress


def _graph_summary(args, launcher, progress, frames: int, elapsed: float):
    """Print the frames tracked, the per-node table and the summary line: (summary line,
    frames tracked, per-node counts)."""
    processed = progress.count if progress else 0
    print(
        f"[demo] graph done: {processed}/{frames} frames tracked in {elapsed:.1f} s "
        f"({processed / max(elapsed, 1e-9):.2f} frames/s end to end)",
        flush=True,
    )
    nodes = node_frame_counts(launcher)
    print(frame_counts_table(nodes), flush=True)
    published = nodes.get(graph.PLAYER.name, {}).get("out", frames)
    summary = "[demo] " + summary_line(
        published,
        processed,
        dropped_by_node(launcher.reports),
        progress.probe.frames.latencies_ms() if progress else [],
        args.camera_hz or None,
    )
    print(summary, flush=True)
    return summary, processed, nodes


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        camera_rate = _checked_options(args)
    except ValueError as exc:
        return _error(str(exc))

    from vehicle_common.kitti import KittiFormatError
    from vehicle_common.output_paths import make_output_dir

    out = Path(args.output or f"output/demo_{datetime.now():%Y%m%d_%H%M%S}").resolve()
    try:
        make_output_dir(out)
    except KittiFormatError as exc:
        return _error(str(exc))
    print(f"[demo] output folder: {out}", flush=True)
    try:
        root, sequence, frames = _prepare_data(args)
    except (KittiFormatError, OSError, ValueError) as exc:
        return _error(str(exc))
    checkpoint = detector_checkpoint(args.params, args.param, synthetic=not args.kitti_root)
    try:
        camera = _camera_settings(args, checkpoint)
    except ValueError as exc:  # the checkpoint (CheckpointError)
        return _error(f"vehicle_detector.checkpoint: {exc}")

    bag = out / "bag"
    overrides = _graph_overrides(args, root, sequence, frames, bag, [*camera, *camera_rate])
    apply_graph_environment()
    try:
        # the progress display's subscription is an edge the player waits for too
        processes = graph_processes(
            graph.PIPELINE,
            args.params,
            overrides,
            extra_subscriptions=LatencyProbe.EDGES,
            params_out=out / "logs" / "parameters.yaml",
        )
    except (LaunchError, ValueError) as exc:
        return _error(str(exc))

    print(
        f"[demo] starting {len(processes)} nodes on {sequence} ({frames} frames, "
        f"{args.detector} detector); logs in {out / 'logs'}",
        flush=True,
    )
    launcher = GraphLauncher(processes, out / "logs", staged=False)  # the player waits itself
    t0 = time.monotonic()
    code, progress = _run_graph(launcher, frames)
    if code is not None:
        return code
    elapsed = time.monotonic() - t0
    summary, processed, nodes = _graph_summary(args, launcher, progress, frames, elapsed)
    if args.no_eval:
        return 0
    code = _evaluate(bag, root, sequence, out, processed, elapsed, args.params, nodes)
    print(summary, flush=True)  # the run's last line
    return code


def node_frame_counts(launcher: GraphLauncher) -> dict[str, dict[str, int]]:
    """Frames in / out / dropped of every node, from their last /diagnostics report."""
    return {
        name: {"in": r.counts.received, "out": r.counts.published, "dropped": r.counts.dropped}
        for name, r in launcher.reports.items()
    }


def frame_counts_table(nodes: dict[str, dict[str, int]]) -> str:
    lines = [f"[demo] {'node':<18} {'frames in':>9} {'out':>6} {'dropped':>8}"]
    for name in [n.name for n in graph.PIPELINE if n.name in nodes]:
        c = nodes[name]
        lines.append(f"[demo] {name:<18} {c['in']:>9} {c['out']:>6} {c['dropped']:>8}")
    return "\n".join(lines)


def _evaluate(
    bag: Path,
    root: Path,
    sequence: str,
    out: Path,
    processed: int,
    elapsed: float,
    params: list[Path],
    nodes: dict[str, dict[str, int]],
):
    from eval_node.bag_evaluation import evaluate_bag
    from eval_node.cli import write_json
    from eval_node.report import results_table, write_report
    from tracker_node.config import TrackerConfig
    from vehicle_common.bags.recorded_run import read_run

    labels = root / "label_02"
    run = read_run(bag, progress=True)  # read once for the evaluation and the report
    results = evaluate_bag(
        bag,
        run=run,
        labels_dir=labels if labels.is_dir() else None,
        sequence=sequence,
        # the filter comparison = the live graph (its parameters: the layered files)
        tracker_config=TrackerConfig.from_dict(
            graph.file_parameters(params)[graph.TRACKER.name], source=describe(params)
        ),
        progress=True,
    )
    results["demo"] = {
        "frames_tracked": processed,
        "wall_time_s": round(elapsed, 2),
        "end_to_end_fps": round(processed / max(elapsed, 1e-9), 3),
        "node_frames": nodes,  # frames in / out / dropped per node
    }
    write_json(out / "results.json", results)
    files = write_report(results, out / "report", run=run, images_dir=root)
    print(results_table(results))
    print(f"[demo] report: {files.get('md', out / 'report')}")
    print(f"[demo] everything is in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
