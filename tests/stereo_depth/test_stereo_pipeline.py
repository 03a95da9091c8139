"""The stereo node's frame path as a core (stereo_depth_node.pipeline) and its offline tool."""

from __future__ import annotations

import csv
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from stereo_depth_node.parameters import stereo_config_from_values
from stereo_depth_node.pipeline import StereoPipeline
from vehicle_common.kitti import TrackingSequence
from vehicle_common.node_parameters import ParameterError

from stereo_depth_node import offline


def _run(seq, pipeline, frames):
    """(frame, index, position, plausibility) of every kept detection of the oracle's boxes."""
    out = []
    for frame in frames:
        left, right = seq.read_stereo(frame)
        if pipeline.settings is None:
            pipeline.camera_from_projections(left, seq.calib.P2, seq.calib.P3)
        boxes = offline.oracle_boxes(seq, frame, ("Car", "Van"))
        geometry, settings = pipeline.camera()
        params = pipeline.disparity_params_for(left.shape[0], settings)
        r = pipeline.process(frame * offline.FRAME_NS, left, right, geometry, params, boxes)
        out += [(frame, i, tuple(rr.position), c.plausibility) for i, rr, c, _ in r.kept]
        assert r.motion is not None or frame == frames[0]  # the odometry from frame 2 on
        pipeline.frame_done(boxes.boxes)
    return out


def test_the_helper_thread_gives_the_serial_results(kitti_tracking_root):
    """The node's helper thread (odometry, road plane, corners ahead) and the offline tools'
    serial executor give the same 3D detections on real 0005."""
    seq = TrackingSequence.open(kitti_tracking_root, "0005")
    config = stereo_config_from_values({})
    serial = _run(seq, StereoPipeline.from_config(config), seq.frame_ids[:3])
    with ThreadPoolExecutor(1) as pool:
        threaded = _run(seq, StereoPipeline.from_config(config, executor=pool), seq.frame_ids[:3])
    assert len(serial) >= 6 and serial == threaded


def test_offline_tool_ranges_the_ground_truth_boxes(kitti_tracking_root, tmp_path):
    """``stereo_offline --oracle`` on real 0005: one row per ranged box, its depth within 10 %
    (+ 1 m) of the label's."""
    out = tmp_path / "det3d.csv"
    rc = offline.main(
        ["--kitti-root", str(kitti_tracking_root), "--sequence", "0005", "--oracle"]
        + ["--output", str(out), "--frames", "3", "-p", "map_area:=band"]
    )
    assert rc == 0
    rows = list(csv.DictReader(out.open()))
    seq = TrackingSequence.open(kitti_tracking_root, "0005")
    assert len(rows) >= 6
    for row in rows:
        gt = [o for o in seq.objects(int(row["frame"])) if o.type in ("Car", "Van")]
        z_gt = gt[int(row["index"])].location[2]
        assert abs(float(row["z"]) - z_gt) < 0.1 * z_gt + 1.0, (row, z_gt)


def test_offline_tool_bad_input_is_one_line(kitti_tracking_root, tmp_path, capsys):
    args = ["--kitti-root", str(kitti_tracking_root), "--sequence", "0005"]
    out = ["--output", str(tmp_path / "x.csv")]
    assert offline.main([*args, "--detections", str(tmp_path / "none"), *out]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {tmp_path / 'none'}: no such folder of detection files"]
    assert offline.main([*args, "--oracle", *out, "-p", "map_area:=road"]) == 2
    assert capsys.readouterr().err.strip().startswith("error: map_area: 'road' is not one of")


def test_parameter_values_are_checked_as_the_node_does():
    config = stereo_config_from_values({"ranging_method": "median", "nice": 5})
    assert config.ranging.method == "median" and np.isclose(config.node.points_max_depth, 80)
    with pytest.raises(ParameterError, match="wls_lambda"):
        stereo_config_from_values({"wls_lambda": -1.0})
    with pytest.raises(ParameterError, match="min_hits: unknown parameter"):
        stereo_config_from_values({"min_hits": 3})


def test_a_band_map_computed_beside_the_cnn_gives_the_same_detections(kitti_tracking_root):
    """Issue #39 (bench_side_by_side): the band's map given to ``process`` (computed while the
    CNN ran) ranges the boxes exactly as the band's map computed inside it."""
    from stereo_depth_node.disparity import compute_disparity

    seq = TrackingSequence.open(kitti_tracking_root, "0005")
    config = stereo_config_from_values({"map_area": "band"})
    inside, given = StereoPipeline.from_config(config), StereoPipeline.from_config(config)
    for frame in seq.frame_ids[:3]:
        left, right = seq.read_stereo(frame)
        boxes = offline.oracle_boxes(seq, frame, ("Car", "Van"))
        out = []
        for pipeline, precomputed in ((inside, False), (given, True)):
            if pipeline.settings is None:
                pipeline.camera_from_projections(left, seq.calib.P2, seq.calib.P3)
            geometry, settings = pipeline.camera()
            params = pipeline.disparity_params_for(left.shape[0], settings)
            disparity = compute_disparity(left, right, params) if precomputed else None
            stamp = frame * offline.FRAME_NS
            r = pipeline.process(stamp, left, right, geometry, params, boxes, disparity=disparity)
            out.append([(i, tuple(rr.position)) for i, rr, _, _ in r.kept])
        assert out[0] == out[1] and out[0]


def test_frame_boxes_from_a_detectors_detections():
    from types import SimpleNamespace

    from stereo_depth_node.pipeline import FrameBoxes

    dets = [
        SimpleNamespace(
            box=(1.0, 2.0, 30.0, 40.0),
            orientation_bin=k,
            observation_angle=0.1 * k,
            observation_angle_variance=0.01,
            score=0.5 + 0.1 * k,
        )
        for k in range(2)
    ]
    b = FrameBoxes.from_detections(dets)
    assert len(b) == 2 and b.bins == [0, 1] and b.angles == [0.0, 0.1] and b.ids == ["0", "1"]
    assert b.scores == [0.5, 0.6] and b.boxes[1] == (1.0, 2.0, 30.0, 40.0)
