"""The detector's real split (detector_node.real_split): reporting sequences, training frames,
cross-validation folds, and the label matching that says which object frames and crops are
frames of which tracking sequence (recomputed here from ../shared/kitti's labels)."""

from __future__ import annotations

import numpy as np
import pytest
from detector_node.dataset import frames_from_source, load_full_sample
from vehicle_common.box2d import iou_2d

from detector_node import real_split as rs

MATCH_TYPES = ("Car", "Van", "Truck", "Tram", "Pedestrian", "Person_sitting", "Cyclist", "Misc")
CROP_X0, CROP_Y0, CROP = 445, 11, 352  # object_crops352: native window of a 1242x375 frame


@pytest.fixture(scope="module")
def tracking_boxes(shared_kitti):
    """Every box of every labelled tracking frame here: (boxes (M, 4), sequence of each (M,),
    start of each frame's rows (F,), sequence of each frame (F,)), rows grouped by frame."""
    from vehicle_common.kitti import read_tracking_labels

    boxes, seqs, starts, frame_seqs = [], [], [], []
    for f in sorted((shared_kitti / "tracking" / "training" / "label_02").glob("*.txt")):
        for objs in read_tracking_labels(f).values():
            b = [o.bbox for o in objs if o.type in MATCH_TYPES]
            if b:
                starts.append(len(seqs))
                frame_seqs.append(f.stem)
                boxes += b
                seqs += [f.stem] * len(b)
    return np.array(boxes, float), np.array(seqs), np.array(starts), np.array(frame_seqs)


def _matching_sequences(boxes, tracking, each: float, mean: float, crop: bool = False):
    """Sequences with a frame whose boxes match every box of ``boxes`` at IoU > ``each`` with a
    mean IoU > ``mean`` (``crop``: the tracking boxes shifted into the crop window, those whose
    centre lies outside it left out, first)."""
    tb, _, starts, frame_seqs = tracking
    if crop:
        tb = tb - np.array([CROP_X0, CROP_Y0, CROP_X0, CROP_Y0])
        cx, cy = (tb[:, 0] + tb[:, 2]) / 2, (tb[:, 1] + tb[:, 3]) / 2
        inside = (cx >= 0) & (cx < CROP) & (cy >= 0) & (cy < CROP)
        tb = np.clip(tb, 0, CROP)
    iou = iou_2d(np.asarray(boxes, float), tb)
    if crop:
        iou[:, ~inside] = -1.0
    best = np.maximum.reduceat(iou, starts, axis=1)  # (N, F): best box of each frame
    ok = (best > each).all(axis=0) & (best.mean(axis=0) > mean)
    return set(frame_seqs[ok].tolist())


def test_object_frames_of_tracking_sequences_are_the_ones_found_by_their_labels(
    shared_kitti, tracking_boxes
):
    from vehicle_common.kitti import read_object_labels

    found = {}
    for i in rs.OBJECT_IDS:
        objs = read_object_labels(shared_kitti / "object" / "training" / "label_2" / f"{i:06d}.txt")
        b = np.array([o.bbox for o in objs if o.type in MATCH_TYPES]).reshape(-1, 4)
        seqs = _matching_sequences(b, tracking_boxes, 0.85, 0.95) if len(b) else set()
        assert len(seqs) <= 1, (i, seqs)
        if seqs:
            found[i] = seqs.pop()
    assert found == rs.OBJECT_FRAME_SEQUENCE
    assert set(rs.REPORT_OBJECT_IDS) == {7, 9, 27, 33, 52, 59, 60, 71, 72, 80, 93}
    assert rs.OBJECT_FRAME_SEQUENCE[80] == "0005"  # 2 frames before keyframe 0005/000209


def test_crops_that_may_be_frames_of_a_sequence_are_the_ones_found_by_their_labels(
    shared_kitti, tracking_boxes
):
    from vehicle_common.kitti import read_object_labels

    report, training = set(), {}
    for lab in sorted((shared_kitti / "object_crops352" / "label_2").glob("*.txt")):
        b = np.array([o.bbox for o in read_object_labels(lab)]).reshape(-1, 4)
        seqs = _matching_sequences(b, tracking_boxes, 0.7, 0.8, crop=True) if len(b) else set()
        if seqs & set(rs.REPORT_SEQUENCES):
            report.add(int(lab.stem))
        elif seqs:
            training[int(lab.stem)] = tuple(sorted(seqs))
    assert report == set(rs.REPORT_CROP_IDS)
    assert {135, 138, 218} <= report  # the former split's image checks found these three
    assert training == rs.CROP_SEQUENCES


def test_reporting_split_is_whole_sequences_disjoint_from_training(shared_kitti):
    rep = [r for s in rs.report_sources(shared_kitti) for r in frames_from_source(s)]
    train = [r for s in rs.train_sources(shared_kitti) for r in frames_from_source(s)]
    crops = frames_from_source(rs.partial_source(shared_kitti))
    assert (len(rep), len(train), len(crops)) == (90, 132, 110)
    assert sum(o.type == "Car" for r in rep for o in r.objects) == 449
    assert not {r.image_path for r in rep} & {r.image_path for r in train}
    # the graph's demo sequence is reported on, never trained on
    assert sum(r.name.startswith("0005/") for r in rep) == 16
    assert not any(r.name.startswith(("kf0005/", "kf0001/", "kf0008/", "kf0010/")) for r in train)
    trained_ids = {int(r.image_path.stem) for r in train if r.image_path.parent.name == "image_2"}
    trained_ids &= set(rs.OBJECT_IDS)
    assert not {rs.OBJECT_FRAME_SEQUENCE.get(i) for i in trained_ids} & set(rs.REPORT_SEQUENCES)
    assert not {int(r.image_path.stem) for r in crops} & set(rs.REPORT_CROP_IDS)
    sizes = {load_full_sample(r, ("Car",)).image.shape[:2] for r in train}
    assert (375, 1242) in sizes and len(sizes) > 1  # object frames of other sizes are read


def test_cv_folds_partition_the_training_frames_by_whole_sequences(shared_kitti):
    train = {r.image_path for s in rs.train_sources(shared_kitti) for r in frames_from_source(s)}
    scored_all = []
    for k in range(len(rs.CV_FOLDS)):
        d = rs.cv_fold_sources(shared_kitti, k)
        scored = [r for s in d["scored"] for r in frames_from_source(s)]
        trained = [
            r for key in ("keyframes", "object") for s in d[key] for r in frames_from_source(s)
        ]
        crops = {int(r.image_path.stem) for s in d["partial"] for r in frames_from_source(s)}
        assert not {r.image_path for r in scored} & {r.image_path for r in trained}
        assert {r.image_path for r in scored} | {r.image_path for r in trained} == train

        # no sequence is both scored and trained on in a fold
        def seq(r):
            if r.name.startswith("kf"):
                return r.name[2:6]
            return rs.OBJECT_FRAME_SEQUENCE.get(int(r.image_path.stem))

        assert not ({seq(r) for r in scored} & {seq(r) for r in trained}) - {None}
        fold_seqs = set(rs.CV_FOLDS[k][0])
        assert not any(set(rs.CROP_SEQUENCES.get(c, ())) & fold_seqs for c in crops)
        scored_all += [r.image_path for r in scored]
    assert len(scored_all) == len(set(scored_all)) == len(train)
    with pytest.raises(ValueError, match="fold"):
        rs.cv_fold_sources(shared_kitti, 3)


def test_id_spec_round_trips_through_the_source_syntax():
    from detector_node.dataset import _expand_ids

    ids = [0, 1, 2, 5, 7, 8, 100, 154, 2100, 2101]
    assert rs.id_spec(ids) == "0-2,5,7-8,100,154,2100-2101"
    assert sorted(_expand_ids(rs.id_spec(ids).split(","))) == ids
