"""kitti_synth for a stereo camera that is not KITTI's: another size, focal length and
baseline (e.g. 1280x720, 700 px, 0.12 m); the pair is rectified with that geometry."""

from __future__ import annotations

import numpy as np
import pytest
from kitti_player_node.synthetic import generate_sequence, main
from vehicle_common.kitti import TrackingSequence


def test_720p_short_baseline_sequence(tmp_path):
    root = generate_sequence(
        tmp_path,
        "0000",
        frames=2,
        seed=1,
        vehicles=6,
        width=640,
        height=360,
        focal=350.0,
        baseline=0.12,
    )
    seq = TrackingSequence.open(root, "0000")
    left, right = seq.read_stereo(1)
    assert left.shape == right.shape == (360, 640, 3)
    assert seq.calib.fx == pytest.approx(350.0) and seq.calib.baseline == pytest.approx(0.12)
    np.testing.assert_allclose(seq.calib.K[:2, 2], [320.0, 180.0])
    # a labelled car's disparity is f * B / z: the rendered pair has that geometry
    from stereo_depth_node.disparity import DisparityParams, compute_disparity

    disp = compute_disparity(left, right, DisparityParams(num_disparities=32))
    cars = [o for o in seq.objects(1) if o.type == "Car" and o.occluded == 0 and o.truncated == 0]
    assert cars
    for o in cars:
        x1, y1, x2, y2 = (int(v) for v in o.bbox)
        d = disp[y1:y2, x1:x2]
        z = float(seq.calib.cam0_to_left(o.location)[2])
        assert np.median(d[d > 0]) == pytest.approx(350.0 * 0.12 / z, rel=0.3)


def test_cli_camera_arguments(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["--output", str(out), "--frames", "1", "--baseline", "0"]) == 2
    assert capsys.readouterr().err.strip() == "error: --baseline: must be 0.01..5 m, got 0.0"
    assert main(["--output", str(out), "--frames", "1", "--focal", "-3"]) == 2
    assert capsys.readouterr().err.strip().startswith("error: --focal: must be 0")
