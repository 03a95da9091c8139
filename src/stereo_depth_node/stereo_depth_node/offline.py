"""``stereo_offline``: the stereo node's frame path over a KITTI tracking sequence, without ROS:
2D boxes in, 3D detections out (one CSV file), through the same core as the node
(:class:`.pipeline.StereoPipeline`, same parameters: the ``stereo_depth`` section of a ROS
parameter file plus ``-p NAME:=VALUE``).

    python -m stereo_depth_node.offline --kitti-root ROOT --sequence 0005
        (--detections DIR | --oracle) --output FILE.csv [--params FILE.yaml] [-p NAME:=VALUE]

The 2D boxes: ``--detections DIR`` reads ``detector_offline``'s result files (``NNNNNN.txt`` per
frame, KITTI object format with a score; its alpha is the continuous observation angle), or
``--oracle`` the sequence's ground truth (``label_02``: the ``--types``, not DontCare; the
label's alpha), as the graph's oracle detector. Each box's orientation bin is its alpha's.

The output has one row per 3D detection: ``frame, index, x1, y1, x2, y2, score, x, y, z,
disparity, valid_pixel_fraction, metric_height, metric_width, bottom_height, plausibility,
plausible`` (index: the box's row in its frame's input; score: the 2D score, times the
plausibility with ``plausibility_action: score``; x, y, z [m]: the box's centre in the left
camera's optical frame, as on ``/vehicles/detections_3d``). The frames are processed in order,
as the node does in lockstep (the odometry and the road plane carry over). Bad input: one line
``error: ...`` on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import yaml
from vehicle_common.kitti import KittiFormatError, TrackingSequence, read_object_labels
from vehicle_common.node_parameters import ParameterError
from vehicle_common.orientation_bins import alpha_to_bin, fold_alpha_signed

from .parameters import stereo_config_from_values
from .pipeline import FrameBoxes, StereoPipeline

NODE_NAME = "stereo_depth"
#: [ns] between KITTI frames (10 Hz)
FRAME_NS = 100_000_000
COLUMNS = [
    "frame",
    "index",
    "x1",
    "y1",
    "x2",
    "y2",
    "score",
    "x",
    "y",
    "z",
    "disparity",
    "valid_pixel_fraction",
    "metric_height",
    "metric_width",
    "bottom_height",
    "plausibility",
    "plausible",
]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="stereo_offline",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--kitti-root", type=Path, required=True, help="KITTI tracking root")
    p.add_argument("--sequence", required=True, help="tracking sequence, e.g. 0005")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--detections", type=Path, help="folder of detector_offline's files")
    src.add_argument("--oracle", action="store_true", help="the ground truth's 2D boxes")
    p.add_argument("--types", default="Car,Van", help="the oracle's object types")
    p.add_argument("--output", type=Path, required=True, help="CSV file of the 3D detections")
    p.add_argument("--params", type=Path, help="ROS parameter YAML (its stereo_depth section)")
    p.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE")
    p.add_argument("--frames", type=int, default=0, help="frames to process (0 = all)")
    return p


def parameter_values(params: Path | None, overrides: list[str]) -> dict:
    """The ``stereo_depth`` section of a ROS parameter file (none: {}) updated by ``NAME:=VALUE``
    overrides (YAML values); KittiFormatError (one line) for a bad file or override."""
    values: dict = {}
    if params is not None:
        try:
            data = yaml.safe_load(params.read_text())
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
            raise KittiFormatError(f"{params}: cannot read the parameter file ({exc})") from None
        for key in (NODE_NAME, "/" + NODE_NAME, "/**"):
            section = data.get(key) if isinstance(data, dict) else None
            if isinstance(section, dict) and isinstance(section.get("ros__parameters"), dict):
                values.update(section["ros__parameters"])
    for item in overrides:
        name, sep, raw = item.partition(":=")
        if not sep or not name:
            raise KittiFormatError(f"-p {item}: expected NAME:=VALUE")
        values[name] = yaml.safe_load(raw)
    return values


def oracle_boxes(seq: TrackingSequence, frame: int, types: tuple[str, ...]) -> FrameBoxes:
    """The frame's ground-truth boxes as the oracle detector gives them (score 1)."""
    objs = [o for o in seq.objects(frame) if o.type in types]
    return _boxes(objs, [1.0] * len(objs))


def detection_boxes(folder: Path, frame: int) -> FrameBoxes:
    """The frame's boxes from ``detector_offline``'s file ``folder/NNNNNN.txt``."""
    path = folder / f"{frame:06d}.txt"
    if not path.is_file():
        raise KittiFormatError(f"{path}: no detection file for frame {frame}")
    objs = read_object_labels(path)
    return _boxes(objs, [o.score for o in objs])


def _boxes(objs, scores) -> FrameBoxes:
    alphas = [float(o.alpha) for o in objs]
    return FrameBoxes(
        [list(o.bbox) for o in objs],
        [alpha_to_bin(a) for a in alphas],
        [fold_alpha_signed(a) for a in alphas],
        [0.0] * len(objs),
        list(scores),
        [str(i) for i in range(len(objs))],
    )


def _row(frame: int, i: int, boxes: FrameBoxes, r, c, score) -> list:
    m = c.measures
    return [
        frame,
        i,
        *(f"{v:.2f}" for v in (boxes.boxes[i] if r.box is None else r.box)),
        f"{boxes.scores[i] if score is None else score:.4f}",
        *(f"{v:.3f}" for v in r.position),
        f"{r.disparity:.3f}",
        f"{r.valid_pixel_fraction:.3f}",
        f"{m.height:.3f}",
        f"{m.width:.3f}",
        f"{m.bottom_height:+.3f}",
        f"{c.plausibility:.3f}",
        int(bool(c.plausible)),
    ]


def run(args: argparse.Namespace) -> int:
    config = stereo_config_from_values(parameter_values(args.params, args.param))
    if args.detections is not None and not args.detections.is_dir():
        raise KittiFormatError(f"{args.detections}: no such folder of detection files")
    seq = TrackingSequence.open(args.kitti_root, args.sequence)
    frames = seq.frame_ids[: args.frames] if args.frames > 0 else seq.frame_ids

    def log(level: str, line: str) -> None:
        if level != "debug":
            print(f"[{level}] {line}", file=sys.stderr)

    pipeline = StereoPipeline.from_config(config, log=log)
    types = tuple(t for t in args.types.split(",") if t)
    rows = []
    for n, frame in enumerate(frames):
        left, right = seq.read_stereo(frame)
        if n == 0:
            log("info", pipeline.camera_from_projections(left, seq.calib.P2, seq.calib.P3))
        boxes = (
            oracle_boxes(seq, frame, types)
            if args.oracle
            else detection_boxes(args.detections, frame)
        )
        geometry, settings = pipeline.camera()
        params = pipeline.disparity_params_for(left.shape[0], settings)
        stamp = frame * FRAME_NS  # the odometry's time step
        result = pipeline.process(stamp, left, right, geometry, params, boxes)
        rows += [_row(frame, i, boxes, r, c, s) for i, r, c, s in result.kept]
        pipeline.frame_done(boxes.boxes)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    with args.output.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(COLUMNS)
        writer.writerows(rows)
    print(f"{len(frames)} frames, {len(rows)} 3D detections -> {args.output}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except (KittiFormatError, ParameterError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
