"""The CenterNet's ONNX Runtime backend, the graph's peephole fusions, the region of interest
and the orientation head's box geometry under another framing."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from detector_node.centernet import CenterNetDetector
from detector_node.checkpoint import load_checkpoint, set_inference_framing
from detector_node.inference import CnnDetector, resolve_runtime
from detector_node.model import DetectorConfig, preset
from detector_node.onnx_backend import onnxruntime_available

needs_ort = pytest.mark.skipif(not onnxruntime_available(), reason="onnxruntime not installed")


@pytest.fixture(scope="module")
def shipped():
    torch.manual_seed(0)
    model, state = load_checkpoint("centernet_kitti", "cpu")
    return model, state


def _unfused(state) -> CenterNetDetector:
    """The shipped weights in a graph built with zero constants and never fused."""
    import json

    config = DetectorConfig.from_dict(state["config"])
    m = CenterNetDetector(config, json.loads(state["graph"]), None)
    m.load_state_dict(state["state_dict"])
    return m.eval()


def test_fusions_apply_after_loading_and_keep_the_output(shipped):
    model, state = shipped
    ops = [o[1] for o in model.graph.ops]
    # MobileNetV3: hard-swish activations and the squeeze-excite gates' hard sigmoids
    assert ops.count("_HardSwish") >= 10 and ops.count("_HardSigmoid") >= 5
    plain = _unfused(state)
    assert "_HardSwish" not in [o[1] for o in plain.graph.ops]
    x = torch.rand(1, 3, 96, 160, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        a, b = model.features(x), plain.features(x)
    assert torch.allclose(a, b, atol=1e-4, rtol=1e-4)


@needs_ort
@pytest.mark.parametrize("hw", [(96, 160), (128, 224)])
def test_onnx_runtime_matches_the_torch_module(shipped, hw):
    """Feature, dense heads and the whole raw output (orientation at the peaks included) agree
    with PyTorch, at sizes where TensorFlow's SAME padding is asymmetric (stride 2 on even
    sides) and the legacy 2x bilinear upsampling is exercised."""
    from detector_node.onnx_backend import OnnxCenterNet

    model, _ = shipped
    x = torch.rand(1, 3, *hw, generator=torch.Generator().manual_seed(2))
    runner = OnnxCenterNet(model, threads=1)
    with torch.no_grad():
        f_ref = model.features(x)
        d_ref = model.dense(f_ref)
        raw_ref = model(x)
    f, d = runner.dense(x)
    assert f.shape == f_ref.shape and d.shape == d_ref.shape
    assert torch.allclose(f, f_ref, atol=1e-4, rtol=1e-4)
    assert torch.allclose(d, d_ref, atol=2e-3, rtol=1e-4)  # box distances are x16 px
    raw = runner(x)
    assert torch.allclose(raw, raw_ref, atol=2e-3, rtol=1e-3)


def test_runtime_resolution():
    cpu = torch.device("cpu")
    centernet, tiny = preset("centernet"), preset("tiny")
    assert resolve_runtime("torch", centernet, cpu) == "torch"
    assert resolve_runtime("auto", tiny, cpu) == "torch"
    expected = "onnxruntime" if onnxruntime_available() else "torch"
    assert resolve_runtime("auto", centernet, cpu) == expected
    with pytest.raises(ValueError, match="runtime: must be one of"):
        resolve_runtime("tensorrt", centernet, cpu)
    with pytest.raises(ValueError, match="needs a CenterNet"):
        resolve_runtime("onnxruntime", tiny, cpu)


@needs_ort
def test_both_runtimes_give_the_same_detections():
    rgb = np.random.default_rng(3).integers(0, 255, (375, 1242, 3), dtype=np.uint8)
    rgb[200:300, 400:600] = (40, 40, 60)  # something box-like
    a = CnnDetector.from_checkpoint("centernet_kitti", "cpu", 0.05, runtime="onnxruntime")
    b = CnnDetector.from_checkpoint("centernet_kitti", "cpu", 0.05, runtime="torch")
    da, db = a.detect(rgb), b.detect(rgb)
    assert len(da) == len(db)
    for p, q in zip(da, db, strict=True):
        assert np.allclose(p.box, q.box, atol=0.05) and abs(p.score - q.score) < 1e-3
        assert p.orientation_bin == q.orientation_bin


def test_roi_top_leaves_the_top_out_and_shifts_the_boxes_back(shared_kitti):
    from vehicle_common.kitti import read_png

    rgb = read_png(shared_kitti / "tracking/training/image_02/0005/000000.png")
    full = CnnDetector.from_checkpoint("centernet_kitti", "cpu", 0.3, runtime="torch")
    assert full.roi_top == 0.25  # the shipped checkpoint's framing
    top = round(0.25 * rgb.shape[0])
    cropped = CnnDetector.from_checkpoint(
        "centernet_kitti", "cpu", 0.3, runtime="torch", roi_top=0.0
    )
    a = full.detect(rgb)
    b = cropped.detect(np.ascontiguousarray(rgb[top:]))
    assert len(a) == len(b) > 0
    for p, q in zip(a, b, strict=True):
        assert np.allclose(p.box, (q.box[0], q.box[1] + top, q.box[2], q.box[3] + top), atol=1e-3)
        assert p.box[1] >= top - 1e-6
        assert abs(p.score - q.score) < 1e-6


def test_geo_frame_maps_another_framing_onto_the_training_framing(tmp_path):
    """The orientation head's box features (log aspect, normalised centre) of a box are those
    it had in training (the shipped head: 1242x375 below the top 25 % at 896x224), whatever the
    input framing (here the whole image at 1024x320)."""
    shipped = CnnDetector.from_checkpoint("centernet_kitti", "cpu", runtime="torch")
    assert shipped._training_input == (896, 224) and shipped._training_roi_top == 0.25
    W, H = 1242, 375
    t_top = round(0.25 * H)
    assert shipped._geo_frame(W, H, t_top, (896 / W, 224 / (H - t_top))) is None
    other = tmp_path / "whole.pt"
    set_inference_framing("centernet_kitti", other, 1024, 320, 0.0)
    det = CnnDetector.from_checkpoint(str(other), "cpu", runtime="torch")
    assert det._training_input == (896, 224) and det._training_roi_top == 0.25
    box = np.array([500.0, 180.0, 620.0, 240.0])  # original px
    tx, ty = 896 / W, 224 / (H - t_top)  # training framing
    bt = (box - [0, t_top, 0, t_top]) * [tx, ty, tx, ty]
    ref = [
        math.log((bt[2] - bt[0]) / (bt[3] - bt[1])),
        (bt[0] + bt[2]) / 2 / 896 - 0.5,
        (bt[1] + bt[3]) / 2 / 224 - 0.5,
    ]
    sx, sy = 1024 / W, 320 / H  # this framing: whole image, 1024x320
    ax, bx, ay, by, aspect = det._geo_frame(W, H, 0, (sx, sy))
    bi = box * [sx, sy, sx, sy]
    got = [
        math.log((bi[2] - bi[0]) / (bi[3] - bi[1])) + aspect,
        (bi[0] + bi[2]) / 2 * ax + bx - 0.5,
        (bi[1] + bi[3]) / 2 * ay + by - 0.5,
    ]
    assert np.allclose(got, ref, atol=1e-9)


def test_set_inference_framing_keeps_weights_and_training_input(tmp_path):
    out = tmp_path / "c.pt"
    set_inference_framing("centernet_kitti", out, 1024, 320, 0.0)
    a, sa = load_checkpoint("centernet_kitti", "cpu")
    b, sb = load_checkpoint(out, "cpu")
    assert (b.config.input_width, b.config.input_height, b.config.roi_top) == (1024, 320, 0.0)
    assert "training_input" not in sa  # trained at its own framing
    assert list(sb["training_input"]) == [896, 224] and sb["training_roi_top"] == 0.25
    for k, v in a.state_dict().items():
        assert torch.equal(v, b.state_dict()[k])
    with pytest.raises(ValueError, match="only CenterNet"):
        set_inference_framing("tiny_kitti", tmp_path / "t.pt", 832, 256, 0.1)
    with pytest.raises(ValueError, match="roi_top"):
        DetectorConfig(roi_top=0.95)


def test_training_frames_are_framed_as_inference_frames_them():
    """With roi_top the training mix leaves the top of each real frame out before the resize,
    so a box lands where inference puts it (896x224 below the top 25 %)."""
    from detector_node.dataset import Sample
    from detector_node.training_data import AugmentConfig, Source, TrainingMix

    img = np.zeros((375, 1242, 3), np.uint8)
    box = np.array([[500.0, 180.0, 620.0, 240.0]], np.float32)
    sample = Sample(img, box, np.array([2]), np.zeros((0, 4), np.float32), (1.0, 1.0), "f")
    aug = AugmentConfig(
        flip=False, photometric=False, crop_probability=0.0, paste_probability=0.0, roi_top=0.25
    )
    mix = TrainingMix([Source("s", "real", [sample])], 896, 224, aug)
    out = mix.make(0, 0, np.random.default_rng(0))
    top = round(0.25 * 375)
    sx, sy = 896 / 1242, 224 / (375 - top)
    expected = (box[0] - [0, top, 0, top]) * [sx, sy, sx, sy]
    assert np.allclose(out.boxes[0], expected, atol=1e-3)
    assert out.image.shape == (224, 896, 3)


def test_heat_map_peaks_without_autograd_match_max_pooling():
    """The detector's peak search (a 3x3 dilation on CPU) finds the cells max pooling finds,
    plateaus and map edges included, with the same scores."""
    import torch
    from detector_node.centernet import HEAT, peaks

    g = torch.Generator().manual_seed(3)
    raw = torch.randn(2, 14, 20, 36, generator=g)
    raw[0, HEAT, 5:7, 8:10] = 4.0  # a plateau: every cell of it is a peak
    raw[1, HEAT, 0, 0] = 5.0  # a corner
    raw[1, HEAT, -1, 17] = 5.0  # an edge
    fast_scores, fast_idx = peaks(raw, 60)
    slow_scores, slow_idx = peaks(raw.clone().requires_grad_(True), 60)  # max_pool2d
    assert torch.equal(fast_scores, slow_scores.detach())
    assert torch.equal(fast_idx, slow_idx)
    assert {5 * 36 + 8, 5 * 36 + 9, 6 * 36 + 8, 6 * 36 + 9} <= set(fast_idx[0].tolist())
    assert {0, 19 * 36 + 17} <= set(fast_idx[1].tolist())


@needs_ort
def test_hard_swish_scale_is_folded_into_the_next_convolutions(shipped):
    """The hard-swish's float16 scale (0.99976) goes into the weights of the convolutions after
    it: a Mul stays only where the scaled value meets an unscaled one in a sum (the parity with
    PyTorch is the test above); there was one Mul per hard-swish."""
    import onnx
    from detector_node.onnx_backend import centernet_to_onnx

    model, _ = shipped
    scales = {n[3]["scale"] for n in model.graph.ops if n[1] == "_HardSwish"}
    assert scales and all(abs(s - 1.0) > 1e-5 for s in scales)  # the factor exists
    m = onnx.load_from_string(centernet_to_onnx(model, 96, 160, image_input=True))
    producer = {o: n for n in m.graph.node for o in n.output}
    consumers = {}
    for n in m.graph.node:
        for i in n.input:
            consumers.setdefault(i, []).append(n.op_type)
    hswish = [n for n in m.graph.node if n.op_type == "HardSwish"]
    scaled = [
        n
        for n in m.graph.node
        if n.op_type == "Mul"
        and n.input[0] in producer
        and producer[n.input[0]].op_type == "HardSwish"
    ]
    assert len(hswish) >= 10
    assert len(scaled) <= 2
    assert all(consumers[n.output[0]] == ["Add"] for n in scaled)
