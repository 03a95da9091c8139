"""Unit tests of the detector core: shapes, orientation bins and flip, box coding, anchors, NMS,
checkpoints, loss overfit, AP."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from detector_node.anchors import kmeans_anchors
from detector_node.augmentation import flip_sample
from detector_node.boxes import decode_raw, encode_box, iou_matrix, nms
from detector_node.checkpoint import load_checkpoint, save_checkpoint
from detector_node.dataset import Sample
from detector_node.inference import decode_output
from detector_node.loss import detection_loss
from detector_node.model import YoloV2Passthrough, preset
from detector_node.validation import FrameResult, evaluate_frames
from vehicle_common.orientation_bins import alpha_to_bin, flip_alpha, flip_bin

torch.set_num_threads(2)


@pytest.mark.parametrize("size", ["tiny", "full"])
def test_output_shapes(size):
    config = preset(size)
    model = YoloV2Passthrough(config).eval()
    with torch.no_grad():
        out = model(torch.zeros(1, 3, config.input_height, config.input_width))
    expected_grid = {"tiny": (6, 20), "full": (11, 36)}[size]
    assert tuple(out.shape) == (1, 45, *expected_grid)
    if size == "full":
        # the paper's table: 11x36x1280 after the passthrough concat, 1024-channel head
        assert model.head[0].in_channels == 1280
        assert model.passthrough[0].out_channels == 64
        assert model.stage6[-1][0].out_channels == 1024
        assert len(model.stage6) == 7 and len(model.stage1to5[4]) == 5


def test_alpha_bins_fold_modulo_180():
    deg = np.radians
    assert alpha_to_bin(0.0) == 0
    assert alpha_to_bin(deg(44.0)) == 1
    assert alpha_to_bin(deg(90.0)) == 2
    assert alpha_to_bin(deg(-90.0)) == 2  # front and back share a class
    assert alpha_to_bin(deg(135.0)) == 3
    assert alpha_to_bin(deg(-45.0)) == 3
    assert alpha_to_bin(deg(170.0)) == 0
    assert alpha_to_bin(deg(-179.0)) == 0
    assert alpha_to_bin(math.pi) == 0


def test_flip_orientation_mapping():
    assert [flip_bin(b) for b in range(4)] == [0, 3, 2, 1]
    # the derivation: flipping alpha (pi - alpha) and then binning equals binning then flip_bin
    alphas = np.linspace(-math.pi + 1e-3, math.pi, 721)
    alphas = alphas[np.abs(np.mod(np.degrees(alphas), 45.0) - 22.5) > 1e-6]  # skip bin edges
    flipped = flip_alpha(alphas)
    assert np.all(flipped > -math.pi) and np.all(flipped <= math.pi)
    assert np.array_equal(alpha_to_bin(flipped), flip_bin(alpha_to_bin(alphas)))
    assert flip_alpha(math.radians(30)) == pytest.approx(math.radians(150))
    assert flip_alpha(math.radians(-30)) == pytest.approx(math.radians(-150))


def test_flip_sample_mirrors_boxes_and_bins():
    img = np.zeros((64, 100, 3), np.uint8)
    img[:, :10] = 255
    s = Sample(
        img, np.array([[10.0, 5, 30, 25]]), np.array([1]), np.array([[0.0, 0, 5, 5]]), (1.0, 1.0)
    )
    f = flip_sample(s)
    assert np.allclose(f.boxes, [[70, 5, 90, 25]])
    assert f.bins.tolist() == [3]
    assert np.allclose(f.dontcare, [[95, 0, 100, 5]])
    assert f.image[0, -1, 0] == 255 and f.image[0, 0, 0] == 0
    back = flip_sample(f)
    assert np.allclose(back.boxes, s.boxes) and back.bins.tolist() == [1]


def test_encode_decode_round_trip():
    anchors = torch.tensor([[20.0, 15.0], [60.0, 40.0]])
    stride = (32.0, 32.0)
    box = np.array([100.3, 40.7, 170.9, 92.2])
    gx, gy, t = encode_box(box, anchors[1].numpy(), stride)
    assert (gx, gy) == (4, 2)
    raw = torch.zeros(1, 2, 4, 3, 6)
    logit = torch.logit(torch.tensor(t[:2], dtype=torch.float32))
    raw[0, 1, :2, gy, gx] = logit
    raw[0, 1, 2:, gy, gx] = torch.tensor(t[2:], dtype=torch.float32)
    decoded = decode_raw(raw, anchors, stride)[0, 1, gy, gx].numpy()
    assert np.allclose(decoded, box, atol=1e-3)


def test_kmeans_anchors_recovers_known_clusters():
    rng = np.random.default_rng(1)
    centres = np.array([[20, 15], [60, 30], [40, 80], [150, 100]], float)
    wh = np.concatenate([c * rng.uniform(0.95, 1.05, (50, 2)) for c in centres])
    anchors, mean_iou = kmeans_anchors(wh, k=4, seed=0)
    assert np.allclose(anchors, centres, rtol=0.06)
    assert mean_iou > 0.9


def test_nms_and_iou():
    boxes = np.array([[0, 0, 10, 10], [1, 1, 10, 10], [20, 20, 30, 30]], float)
    assert iou_matrix(boxes[:1], boxes[1:2])[0, 0] == pytest.approx(81 / 100)
    keep = nms(boxes, np.array([0.5, 0.9, 0.3]), 0.5)
    assert keep.tolist() == [1, 2]


def test_checkpoint_round_trip_weights_only(tmp_path):
    config = preset("tiny", input_width=320, input_height=96, anchors=((10, 8), (30, 20)))
    model = YoloV2Passthrough(config).eval()
    path = tmp_path / "m.pt"
    save_checkpoint(path, model, {"epoch": 3})
    raw = torch.load(path, weights_only=True)
    assert raw["config"]["anchors"] == [[10.0, 8.0], [30.0, 20.0]] and raw["epoch"] == 3
    loaded, _ = load_checkpoint(path)
    assert loaded.config == config
    x = torch.rand(1, 3, 96, 320)
    with torch.no_grad():
        assert torch.allclose(model(x), loaded(x))
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="bad.pt"):
        load_checkpoint(tmp_path / "bad.pt")


def _toy_images(n: int, rng: np.random.Generator):
    """Gray images with bright 'car' rectangles of known boxes and orientation bins."""
    images, boxes, bins = [], [], []
    for i in range(n):
        img = np.full((96, 320, 3), 90, np.uint8)
        x = int(rng.integers(10, 250))
        b = np.array([[x, 40, x + 50, 80]], np.float32)
        img[40:80, x : x + 50] = (200, 40 + 50 * (i % 4), 40)
        images.append(img)
        boxes.append(b)
        bins.append(np.array([i % 4]))
    return images, boxes, bins


def test_loss_decreases_on_tiny_overfit_set():
    torch.manual_seed(0)
    config = preset(
        "tiny",
        input_width=320,
        input_height=96,
        anchors=((20, 15), (50, 40), (100, 60), (30, 60), (150, 80)),
    )
    model = YoloV2Passthrough(config)
    images, boxes, bins = _toy_images(4, np.random.default_rng(0))
    x = torch.from_numpy(np.stack(images)).permute(0, 3, 1, 2).float() / 255
    dc = [np.zeros((0, 4))] * 4
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(150):
        loss, terms = detection_loss(model(x), boxes, bins, dc, config)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert np.mean(losses[-10:]) < 0.2 * np.mean(losses[:5])
    model.eval()
    with torch.no_grad():
        dets = decode_output(model(x), config, score_threshold=0.3, nms_iou=0.45)
    for d, b, o in zip(dets, boxes, bins, strict=True):
        assert d, "overfit model finds the rectangle"
        assert iou_matrix(np.array([d[0].box]), b)[0, 0] > 0.5
        assert d[0].orientation_bin == o[0]
        assert sum(d[0].orientation_probs) == pytest.approx(1.0, abs=1e-5)


def test_dontcare_regions_are_not_background():
    config = preset("tiny", input_width=320, input_height=96)
    raw = torch.zeros(1, 45, 3, 10)
    raw.view(1, 5, 9, 3, 10)[:, :, 4] = 3.0  # confident everywhere
    empty = [np.zeros((0, 4), np.float32)]
    _, no_dc = detection_loss(raw, empty, [np.zeros(0, np.int64)], [np.zeros((0, 4))], config)
    _, with_dc = detection_loss(
        raw, empty, [np.zeros(0, np.int64)], [np.array([[0.0, 0.0, 160.0, 96.0]])], config
    )
    assert with_dc["noobj"] == pytest.approx(no_dc["noobj"] / 2, rel=1e-4)


def test_simple_ap_and_orientation_confusion():
    gt = np.array([[0, 0, 10, 10], [20, 0, 30, 10]], float)
    frames = [
        FrameResult(
            det_boxes=np.array(
                [[0, 0, 10, 10], [21, 0, 31, 10], [50, 50, 60, 60], [80, 0, 90, 10]]
            ),
            det_scores=np.array([0.9, 0.8, 0.7, 0.95]),
            det_bins=np.array([1, 2, 0, 0]),
            gt_boxes=gt,
            gt_bins=np.array([1, 3]),
            dontcare=np.array([[78.0, 0, 92, 12]]),
        )
    ]
    r = evaluate_frames(frames, 0.5)
    # ranked: 0.9 TP, 0.8 TP (IoU 0.82), 0.7 FP; the 0.95 one lies on DontCare (ignored)
    assert r.ap == pytest.approx(1.0)
    assert r.num_det == 3
    assert r.orientation_accuracy == pytest.approx(0.5)
    assert r.confusion[1, 1] == 1 and r.confusion[3, 2] == 1
    r7 = evaluate_frames(frames, 0.85)
    assert r7.ap == pytest.approx(0.5)


def test_orientation_bin_weights_scale_the_orientation_term():
    from detector_node.loss import LossWeights

    config = preset("tiny", input_width=320, input_height=96)
    torch.manual_seed(0)
    raw = torch.randn(1, 45, 3, 10)
    boxes = [np.array([[40.0, 30, 90, 70], [200, 20, 260, 80]], np.float32)]
    bins = [np.array([1, 2])]
    dc = [np.zeros((0, 4))]
    _, plain = detection_loss(raw, boxes, bins, dc, config)
    _, only1 = detection_loss(
        raw, boxes, bins, dc, config, LossWeights(orientation_bin_weights=(0.0, 1.0, 0.0, 0.0))
    )
    _, only2 = detection_loss(
        raw, boxes, bins, dc, config, LossWeights(orientation_bin_weights=(0.0, 0.0, 3.0, 0.0))
    )
    assert only1["ori"] > 0 and only2["ori"] > 0
    assert only1["ori"] + only2["ori"] / 3 == pytest.approx(plain["ori"], rel=1e-5)
    assert only1["box"] == pytest.approx(plain["box"])
