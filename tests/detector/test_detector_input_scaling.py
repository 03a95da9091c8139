"""The CNN's input size for a camera that is not KITTI's: with an overridden input size the
anchors follow each image's input px per image px relative to training, so a 1280x720 image at
896x512 keeps the cars' box heights (they were stretched 2x with the input's aspect before);
a KITTI-sized image gets the anchors it always got. Anchors are the tiny YOLO checkpoint's
(``tiny_kitti``); the shipped CenterNet has none."""

from __future__ import annotations

import numpy as np
import pytest
from detector_node.dataset import resize_image
from detector_node.inference import CnnDetector


@pytest.fixture(scope="module")
def shipped():
    return CnnDetector.from_checkpoint("tiny_kitti", "cpu")


def test_kitti_sized_images_keep_the_input_ratio_anchors(shipped):
    big = CnnDetector.from_checkpoint("tiny_kitti", "cpu", input_width=1152, input_height=352)
    _, scale = resize_image(np.zeros((375, 1242, 3), np.uint8), 1152, 352)
    c = shipped.config
    sx, sy = 1152 / c.input_width, 352 / c.input_height
    want = [[w * sx, h * sy] for w, h in shipped.config.anchors]
    np.testing.assert_allclose(big.config_for(scale).anchors, want, rtol=1e-9)
    assert shipped.config_for(scale) is shipped.config  # no override: the checkpoint's


def test_720p_anchors_keep_the_training_pixel_scale(shipped):
    c = shipped.config
    det = CnnDetector.from_checkpoint("tiny_kitti", "cpu", input_width=896, input_height=512)
    _, scale = resize_image(np.zeros((720, 1280, 3), np.uint8), 896, 512)
    ratio = np.array(det.config_for(scale).anchors) / np.array(c.anchors)
    # 896/1280 = 0.70 and 512/720 = 0.71 input px per image px vs 832/1242 and 256/375
    np.testing.assert_allclose(ratio[:, 0], (896 / 1280) / (c.input_width / 1242), rtol=1e-9)
    np.testing.assert_allclose(ratio[:, 1], (512 / 720) / (c.input_height / 375), rtol=1e-9)
    assert ratio[:, 1].max() < 1.1  # not 2x (512/256) as the input-size ratio would give


def test_720p_synthetic_cars_get_boxes_of_their_height(tmp_path):
    from kitti_player_node.synthetic import generate_sequence
    from vehicle_common.box2d import iou_2d
    from vehicle_common.kitti import TrackingSequence

    root = generate_sequence(
        tmp_path, "0000", frames=1, seed=0, width=1280, height=720, focal=700.0, baseline=0.12
    )
    seq = TrackingSequence.open(root, "0000")
    left, _ = seq.read_stereo(0)
    gt = [
        o.bbox
        for o in seq.objects(0)
        if o.type in ("Car", "Van") and o.occluded == 0 and o.bbox[3] - o.bbox[1] > 25
    ]
    assert gt
    dets = CnnDetector.from_checkpoint(
        "tiny_kitti", "cpu", input_width=896, input_height=512
    ).detect(left)
    m = iou_2d(np.array(gt), np.array([d.box for d in dets]))
    best = m.argmax(axis=1)
    heights = [
        (dets[j].box[3] - dets[j].box[1]) / (g[3] - g[1]) for g, j in zip(gt, best, strict=True)
    ]
    assert 0.75 < np.median(heights) < 1.3  # 1.75 with the stretched anchors
