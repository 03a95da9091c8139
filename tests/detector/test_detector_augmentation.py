"""Augmentations keep boxes and orientation labels right; the training mix samples by weight."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from detector_node.augmentation import (
    CarCrop,
    RowSizeModel,
    collect_car_crops,
    crop_sample,
    flip_sample,
    paste_cars,
    paste_native_crop,
    photometric,
    random_crop,
    resize_sample,
)
from detector_node.dataset import Sample, label_bin, split_objects
from detector_node.loss import detection_loss
from detector_node.model import preset
from detector_node.training_data import AugmentConfig, Source, TrainingMix
from vehicle_common.kitti import KittiObject
from vehicle_common.orientation_bins import alpha_to_bin, flip_alpha


def _sample(boxes, bins, w=200, h=60, dontcare=None, trunc=None) -> Sample:
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
    return Sample(
        img,
        np.array(boxes, np.float32).reshape(-1, 4),
        np.array(bins, np.int64),
        np.array(dontcare if dontcare is not None else [], np.float32).reshape(-1, 4),
        (1.0, 1.0),
        "t",
        None if trunc is None else np.array(trunc, np.float32),
    )


def test_label_bin_unknown_alpha_and_split_objects():
    assert label_bin(-10.0) == -1
    assert label_bin(math.radians(44)) == 1
    objs = [
        KittiObject("Car", alpha=math.radians(135), bbox=(1, 2, 30, 20)),
        KittiObject("Car", alpha=-10.0, bbox=(40, 2, 60, 20)),
        KittiObject("DontCare", bbox=(0, 0, 5, 5)),
        KittiObject("Pedestrian", alpha=0.0, bbox=(70, 2, 80, 20)),
    ]
    boxes, bins, dc = split_objects(objs, ("Car", "Van"))
    assert bins.tolist() == [3, -1] and len(boxes) == 2 and dc.tolist() == [[0, 0, 5, 5]]


def test_flip_mirrors_alpha_bins_of_labelled_objects_and_keeps_unknown():
    alphas = np.radians([10.0, 40.0, 100.0, 150.0, -60.0, -170.0])
    bins = np.array([alpha_to_bin(a) for a in alphas] + [-1])
    boxes = [[10 + 20 * i, 5, 25 + 20 * i, 30] for i in range(len(bins))]
    f = flip_sample(_sample(boxes, bins))
    expected = [alpha_to_bin(flip_alpha(a)) for a in alphas] + [-1]
    assert f.bins.tolist() == expected
    assert np.allclose(f.boxes[0], [200 - 25, 5, 200 - 10, 30])


def test_crop_truncates_clips_and_turns_mostly_cut_boxes_into_ignore_regions():
    s = _sample(
        [[10, 10, 50, 40], [90, 10, 130, 40], [150, 10, 190, 40], [0, 0, 5, 5]],
        [0, 1, 2, 3],
        dontcare=[[100, 0, 200, 20]],
        trunc=[0.0, 0.2, 0.0, 0.0],
    )
    c = crop_sample(s, 30, 5, 130, 50)  # window x 30..160, y 5..55
    # box 0: x 10..50 -> 30..50 kept half (0.5 >= 0.5): positive, truncation 0.5
    # box 1: fully inside; box 2: x 150..190 -> 150..160 = 25 % visible -> ignore region
    # box 3: outside -> dropped
    assert c.bins.tolist() == [0, 1]
    assert np.allclose(c.boxes, [[0, 5, 20, 35], [60, 5, 100, 35]])
    assert np.allclose(c.truncation, [0.5, 0.2])
    assert np.allclose(c.dontcare, [[70, 0, 130, 15], [120, 5, 130, 35]])
    assert np.array_equal(c.image[0, 0], s.image[5, 30])
    assert c.image.shape == (50, 130, 3)


def test_crop_beyond_the_image_pads_and_random_crop_keeps_the_aspect():
    s = _sample([[10, 10, 50, 40]], [2])
    c = crop_sample(s, -20, 0, 240, 72)
    assert np.allclose(c.boxes, [[30, 10, 70, 40]])
    assert np.array_equal(c.image[0, 25], s.image[0, 5])
    rng = np.random.default_rng(3)
    for _ in range(20):
        r = random_crop(s, rng, 0.6, 1.0)
        h, w = r.image.shape[:2]
        assert abs(w / h - 200 / 60) < 0.05


def test_resize_scales_boxes_and_photometric_keeps_labels():
    s = _sample([[10, 10, 50, 40]], [1], dontcare=[[0, 0, 20, 20]])
    r = resize_sample(s, 100, 30)
    assert np.allclose(r.boxes, [[5, 5, 25, 20]]) and np.allclose(r.dontcare, [[0, 0, 10, 10]])
    assert r.scale == (0.5, 0.5)
    p = photometric(r, np.random.default_rng(0), p_blur=1.0, p_noise=1.0)
    assert p.image.shape == r.image.shape and not np.array_equal(p.image, r.image)
    assert np.array_equal(p.boxes, r.boxes) and p.bins.tolist() == [1]


def test_row_size_model_fit_recovers_the_ground_plane_line():
    y2 = np.linspace(200, 370, 30)
    h = 0.9 * (y2 - 180)
    boxes = np.stack([np.zeros_like(y2), y2 - h, 50 + np.zeros_like(y2), y2], 1)
    m = RowSizeModel.fit(boxes)
    assert m.slope == pytest.approx(0.9, abs=1e-6) and m.horizon == pytest.approx(180, abs=1e-4)
    assert m.spread == pytest.approx(0.0, abs=1e-6) and m.y2_range == (200.0, 370.0)


def test_paste_cars_size_for_row_no_overlap_and_mirrored_bin():
    bg = _sample([[0, 100, 60, 150]], [2], w=600, h=200, dontcare=[[500, 0, 600, 200]])
    bg.image[:] = 0
    patch = np.zeros((40, 80, 3), np.uint8)
    patch[:, :40] = 255  # left half white: mirrored when the right half is white
    rows = RowSizeModel(slope=0.5, horizon=80.0, spread=0.0, y2_range=(150.0, 195.0))
    rng = np.random.default_rng(1)
    seen = set()
    for _ in range(10):
        out = paste_cars(bg, [CarCrop(patch, 1)], rows, rng, count=2)
        new = out.boxes[1:]
        assert len(new) >= 1 and out.truncation.tolist() == [0.0] * len(out.boxes)
        for box, b in zip(new, out.bins[1:], strict=True):
            x1, y1, x2, y2 = box.astype(int)
            assert abs((y2 - y1) - rows.height(y2)) <= 1.5  # height plausible for its row
            assert abs((x2 - x1) / (y2 - y1) - 2.0) < 0.1  # crop's aspect kept
            assert x2 <= 500 and not (x1 < 60 and y2 > 100 and y1 < 150)  # no overlap
            mid = out.image[(y1 + y2) // 2, x1:x2, 0].astype(float)
            left_white = mid[: len(mid) // 3].mean() > mid[-len(mid) // 3 :].mean()
            assert b == (1 if left_white else 3)
            seen.add(int(b))
    assert seen == {1, 3}


def test_collect_car_crops_only_clean_cars():
    s = _sample(
        [[10, 10, 50, 45], [40, 20, 80, 50], [100, 5, 150, 50], [160, 30, 190, 40]],
        [1, 2, 0, 3],
    )
    s.occluded = np.array([0, 0, 0, 0])
    crops = collect_car_crops([s], min_height=25)
    # boxes 0 and 1 overlap each other, box 3 too small: only box 2
    assert len(crops) == 1 and crops[0].bin == 0 and crops[0].patch.shape == (45, 50, 3)


def test_paste_native_crop_marks_the_unlabelled_area_as_ignored():
    bg = _sample([[0, 10, 30, 40], [90, 10, 120, 40]], [2, 2], w=300, h=80)
    crop = _sample([[5, 5, 25, 30]], [-1], w=60, h=60)
    out = paste_native_crop(bg, crop, 100, 10)
    assert np.array_equal(out.image[10:70, 100:160], crop.image)
    assert np.allclose(out.boxes, [[0, 10, 30, 40], [105, 15, 125, 40]])
    assert out.bins.tolist() == [2, -1]
    assert np.allclose(out.dontcare, [[90, 10, 120, 40], [100, 10, 160, 70]])


def test_training_mix_samples_by_weight_and_outputs_network_size():
    real = [_sample([[10, 10, 50, 40]], [1], w=320, h=96) for _ in range(3)]
    synth = [_sample([[5, 5, 30, 20]], [2], w=64, h=32)]
    mix = TrainingMix(
        [Source("real", "real", real, 3.0), Source("syn", "synthetic", synth, 1.0)],
        64,
        32,
        AugmentConfig(paste_probability=0.0),
    )
    rng = np.random.default_rng(0)
    picks = mix.draw(4000, rng)
    share = np.mean([k == 0 for k, _ in picks])
    assert share == pytest.approx(0.75, abs=0.03)
    for k, i in picks[:20]:
        s = mix.make(k, i, rng)
        assert s.image.shape == (32, 64, 3) and len(s.boxes) == len(s.bins)
    with pytest.raises(ValueError, match="kind"):
        Source("x", "other", real)


def test_loss_ignores_unknown_orientation():
    config = preset("tiny", input_width=64, input_height=64, anchors=((10, 10),))
    raw = torch.zeros(1, 9, 2, 2)
    raw[0, 5] = 3.0  # strongly predicts bin 0
    boxes = [np.array([[5.0, 5, 15, 15]])]
    _, unknown = detection_loss(raw, boxes, [np.array([-1])], [np.zeros((0, 4))], config)
    _, wrong = detection_loss(raw, boxes, [np.array([2])], [np.zeros((0, 4))], config)
    assert unknown["ori"] == 0.0 and wrong["ori"] > 1.0


def test_crop_keeps_the_occlusion_flags_of_the_boxes_it_keeps():
    # the crop drops the second box: its occlusion flag must go with it, or the training mix's
    # later filter of boxes (resize, < 2 px) indexes a stale array
    from dataclasses import replace

    s = replace(_sample([[10, 10, 50, 40], [150, 10, 190, 40]], [1, 2]), occluded=np.array([2, 0]))
    c = crop_sample(s, 0, 0, 100, 60)
    assert len(c.boxes) == 1
    np.testing.assert_array_equal(c.occluded, [2])


class _FlipAlways:
    """A generator stand-in whose draws make the training mix flip (random() = 0)."""

    def __init__(self, seed=0):
        self._rng = np.random.default_rng(seed)

    def random(self, *a, **k):
        return 0.0

    def __getattr__(self, name):
        return getattr(self._rng, name)


def test_centernet_training_path_flips_alpha_to_pi_minus_alpha_bins_and_boxes():
    """The mirror augmentation as the CenterNet training sees it (TrainingMix.make, as
    detector_train draws both its fresh samples and its feature bank, then the CenterNet
    targets): alpha -> pi - alpha, bins 45 <-> 135 (0 and 90 stay), boxes mirrored."""
    from detector_node.centernet import build_targets
    from detector_node.dataset import sample_alphas

    alphas = np.radians([10.0, 45.0, 90.0, 135.0, -30.0, -150.0]).astype(np.float32)
    boxes = [[10 + 30 * i, 20, 30 + 30 * i, 50] for i in range(len(alphas))]
    s = _sample(boxes, [alpha_to_bin(a) for a in alphas], w=256, h=64)
    s.alphas = alphas
    mix = TrainingMix(
        [Source("real", "real", [s])],
        256,
        64,
        AugmentConfig(flip=True, photometric=False, crop_probability=0, paste_probability=0),
    )
    out = mix.make(0, 0, _FlipAlways())
    flipped = sample_alphas(out)
    np.testing.assert_allclose(flipped, [flip_alpha(a) for a in alphas], atol=1e-6)
    np.testing.assert_allclose(np.degrees(flipped[:4]), [170.0, 135.0, 90.0, 45.0], atol=1e-4)
    assert out.bins.tolist() == [0, 3, 2, 1, 1, 3]  # before: 0, 1, 2, 3, 3, 1
    np.testing.assert_allclose(out.boxes[:, [0, 2]], 256 - s.boxes[:, [2, 0]])
    np.testing.assert_allclose(out.boxes[:, [1, 3]], s.boxes[:, [1, 3]])
    assert np.array_equal(out.image, s.image[:, ::-1])
    # the CenterNet's orientation targets follow: true 45 deg trains bin 135 once mirrored
    _, _, _, _, _, bins, res = build_targets([out.boxes], [flipped], [out.dontcare], 16, 64)
    assert bins.tolist() == [0, 3, 2, 1, 1, 3]
    np.testing.assert_allclose(np.degrees(res[:2]), [-10.0, 0.0], atol=1e-4)
    # and a mix without the flip leaves them as labelled
    mix.aug.flip = False
    kept = mix.make(0, 0, _FlipAlways())
    np.testing.assert_allclose(sample_alphas(kept), alphas)
    assert kept.bins.tolist() == [0, 1, 2, 3, 3, 1]


def test_boxes_keep_where_they_were_seen_through_crops_pastes_framing_and_flips():
    """``Sample.view`` (``detector_train --true-view``): the box centre in its own frame as
    inference frames it (below roi_top), normalised; scale jitter and crops move the box in
    the input, not its view; a flip mirrors it; a pasted car keeps its source's view."""
    from dataclasses import replace

    from detector_node.dataset import sample_view

    s = _sample([[100, 60, 140, 90], [10, 50, 50, 80]], [2, 3], w=400, h=100)
    s.alphas = np.radians([90.0, 130.0]).astype(np.float32)
    crops = collect_car_crops([replace(s, view=np.array([[0.3, 0.75], [0.075, 0.65]]))])
    assert [c.view for c in crops] == [(0.3, 0.75), (0.075, 0.65)]
    mix = TrainingMix(
        [Source("real", "real", [s])],
        200,
        40,
        AugmentConfig(
            flip=False, photometric=False, crop_probability=1.0, paste_probability=0.0, roi_top=0.2
        ),
    )
    moved = 0
    for seed in range(6):
        out = mix.make(0, 0, np.random.default_rng(seed))
        expect = {0: (0.3, (75 - 20) / 80), 1: (0.075, (65 - 20) / 80)}  # below the top 20 %
        now = sample_view(replace(out, view=None))  # where the boxes are in the input
        for k, v in enumerate(out.view):
            i = 0 if np.isclose(v[0], 0.3) else 1
            np.testing.assert_allclose(v, expect[i], atol=1e-6)
            moved += not np.allclose(now[k], expect[i], atol=0.01)
    assert moved  # the crops did move boxes in the input
    f = flip_sample(out)
    np.testing.assert_allclose(f.view[:, 0], 1.0 - out.view[:, 0])
    np.testing.assert_allclose(f.view[:, 1], out.view[:, 1])
    # a pasted car keeps its source's view (mirrored with it), the frame's own boxes theirs
    bg = _sample([[300, 60, 340, 90]], [2], w=400, h=100)
    rows = RowSizeModel(0.5, 20.0, 0.0, (70.0, 95.0))
    got = paste_cars(bg, crops[:1], rows, np.random.default_rng(1), 1)
    assert len(got.boxes) == 2
    np.testing.assert_allclose(got.view[0], [0.8, 0.75])
    assert any(np.allclose(got.view[1], v) for v in ([0.3, 0.75], [0.7, 0.75]))
    assert not np.allclose(sample_view(replace(got, view=None))[1], got.view[1], atol=0.01)


def test_orientation_head_takes_the_view_in_place_of_the_box_position():
    """With a view the head's position inputs are the view (training with --true-view); without
    one, the box centre in the input (inference): the same when the view is that centre."""
    from types import SimpleNamespace

    from detector_node.centernet import CenterNetDetector

    torch.manual_seed(0)
    head = torch.nn.Linear(128 * 9 + 3, 9)
    fake = SimpleNamespace(orientation=head, geo_frame=None)
    f = torch.randn(1, 128, 8, 16)  # an input of 64 x 32 px at stride 4
    boxes = torch.tensor([[8.0, 4.0, 24.0, 20.0], [30.0, 10.0, 50.0, 28.0]])
    batch = torch.zeros(2, dtype=torch.long)
    at = CenterNetDetector.orientation_at
    here = torch.tensor([[16.0 / 64, 12.0 / 32], [40.0 / 64, 19.0 / 32]])
    torch.testing.assert_close(at(fake, f, batch, boxes, here), at(fake, f, batch, boxes))
    elsewhere = torch.tensor([[0.9, 0.5], [0.1, 0.5]])
    moved = at(fake, f, batch, boxes, elsewhere) - at(fake, f, batch, boxes)
    assert (moved.abs() > 1e-6).all()
    # only the position inputs differ: exactly the head's weights on them times the shift
    shift = torch.cat([torch.zeros(2, 1), elsewhere - here], 1)
    torch.testing.assert_close(moved, shift @ head.weight[:, -3:].T)
