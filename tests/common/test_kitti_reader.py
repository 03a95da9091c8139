"""KITTI reader (kitti.py) on the real samples and on malformed input."""

from __future__ import annotations

import numpy as np
import pytest
from vehicle_common.box3d import project_points
from vehicle_common.kitti import KittiFormatError, KittiObject

from vehicle_common import kitti


def test_both_calib_spellings_parse(kitti_tracking_root):
    tracking = kitti_tracking_root / "calib" / "0005.txt"
    assert "R_rect " in tracking.read_text() and "Tr_velo_cam " in tracking.read_text()
    c5 = kitti.read_calib(tracking)
    others = [p for p in sorted((kitti_tracking_root / "calib").glob("*.txt")) if p != tracking]
    assert others and "R0_rect:" in others[0].read_text()
    c1 = kitti.read_calib(others[0])
    for c in (c5, c1):
        assert 0.50 < c.baseline < 0.56
        assert c.fx == pytest.approx(721.5377)
        assert np.linalg.det(c.R_rect) == pytest.approx(1.0, abs=1e-4)
        # R_rect and Tr_velo_cam were read from the file, not left at the defaults
        assert not np.allclose(c.R_rect, np.eye(3))
        assert not np.allclose(c.Tr_velo_cam[:, :3], np.eye(3))
    # left camera sits about 6 cm left of camera 0: p_left = p_cam0 + offset, offset_x ~ +0.06
    P2 = c5.P2
    tz = P2[2, 3]
    tx = (P2[0, 3] - P2[0, 2] * tz) / P2[0, 0]
    np.testing.assert_allclose(c5.left_camera_offset[[0, 2]], [tx, tz], rtol=1e-9)
    assert 0.055 < tx < 0.065


def test_sequence_0005_has_16_stereo_frames_and_dontcare_labels(kitti_tracking_root):
    seq = kitti.TrackingSequence.open(kitti_tracking_root, "0005")
    assert seq.sequence == "0005" and seq.frame_ids == list(range(16))
    left, right = seq.read_stereo(15)
    assert left.shape == right.shape == (375, 1242, 3) and left.dtype == np.uint8
    assert not np.array_equal(left, right)
    objects = [o for f in seq.frame_ids for o in seq.objects(f)]
    dontcare = [o for o in objects if o.is_dontcare]
    assert dontcare and all(o.track_id == -1 for o in dontcare)
    cars = [o for o in objects if o.type == "Car"]
    assert cars and all(o.track_id >= 0 and o.dimensions[0] > 1.0 for o in cars)
    assert all(o.frame == f for f in seq.frame_ids for o in seq.objects(f))
    assert seq.objects(10_000) == []


def test_label_box_centres_project_into_their_2d_boxes(kitti_tracking_root):
    seq = kitti.TrackingSequence.open(kitti_tracking_root, "0005")
    checked = 0
    for f in seq.frame_ids:
        for o in seq.objects(f):
            if o.is_dontcare or o.truncated > 0:
                continue  # truncated boxes are clipped to the image; their centre may lie outside
            u, v = project_points(seq.calib.P2, o.centre_of_mass[None])[0]
            x1, y1, x2, y2 = o.bbox
            assert x1 <= u <= x2 and y1 <= v <= y2, (f, o.track_id, u, v, o.bbox)
            checked += 1
    assert checked >= 20


def test_object_layout_and_demo_pair(shared_kitti, tmp_path):
    demo = shared_kitti / "object_demo"
    calib = kitti.read_calib(demo / "calib.txt")
    left = kitti.read_png(demo / "left.png")
    assert left.shape == kitti.read_png(demo / "right.png").shape
    root = tmp_path / "object"
    (root / "image_2").mkdir(parents=True)
    (root / "image_3").mkdir()
    for fid in ("000007", "000000"):
        kitti.write_png(root / "image_2" / f"{fid}.png", left[:40, :60])
        kitti.write_png(root / "image_3" / f"{fid}.png", left[:40, :60])
        kitti.write_calib(root / "calib" / f"{fid}.txt", calib)
    car = KittiObject("Car", 0.0, 0, -1.5, (10, 5, 50, 30), (1.5, 1.6, 4.0), (1.0, 1.6, 12.0), -1.4)
    kitti.write_object_labels(root / "label_2" / "000007.txt", [car, KittiObject("DontCare")])
    frames = kitti.list_object_frames(root)
    assert [f.frame_id for f in frames] == ["000000", "000007"]
    assert frames[0].objects() == []
    objs = frames[1].objects()
    assert [o.type for o in objs] == ["Car", "DontCare"] and objs[1].is_dontcare
    assert objs[0].bbox == car.bbox and objs[0].location == car.location
    np.testing.assert_allclose(frames[1].calib().P3, calib.P3, rtol=1e-9)
    assert np.array_equal(kitti.read_png(frames[1].right_path), left[:40, :60])


def _tiny_sequence(root, n_left=3, n_right=3):
    img = np.zeros((8, 12, 3), np.uint8)
    for i in range(n_left):
        kitti.write_png(root / "image_02" / "0003" / f"{i:06d}.png", img)
    for i in range(n_right):
        kitti.write_png(root / "image_03" / "0003" / f"{i:06d}.png", img)
    kitti.write_calib(root / "calib" / "0003.txt", kitti.stereo_calibration(100, 100, 6, 4, 0.5))


def test_missing_folder_is_named(tmp_path):
    with pytest.raises(KittiFormatError, match="nowhere"):
        kitti.TrackingSequence.open(tmp_path / "nowhere", "0000")
    _tiny_sequence(tmp_path)
    with pytest.raises(KittiFormatError, match="image_02/0004"):
        kitti.TrackingSequence.open(tmp_path, "0004")


def test_left_right_frame_counts_differ(tmp_path):
    _tiny_sequence(tmp_path, 3, 2)
    with pytest.raises(KittiFormatError, match=r"image_03/0003.*3 in image_02, 2 in image_03"):
        kitti.TrackingSequence.open(tmp_path, "0003")


def test_malformed_calib_and_label_rows_name_file_and_line(tmp_path):
    _tiny_sequence(tmp_path)
    calib = tmp_path / "calib" / "0003.txt"
    lines = calib.read_text().splitlines()
    lines[2] = "P2: 1 2 3"
    calib.write_text("\n".join(lines) + "\n")
    with pytest.raises(KittiFormatError, match=r"calib/0003.txt:3: P2: expected 12 numbers, got 3"):
        kitti.TrackingSequence.open(tmp_path, "0003")
    lines[2] = "P2: 1 2 3 4 5 x 7 8 9 10 11 12"
    calib.write_text("\n".join(lines) + "\n")
    with pytest.raises(KittiFormatError, match=r"0003.txt:3: P2: non-numeric"):
        kitti.read_calib(calib)
    labels = tmp_path / "label_02" / "0003.txt"
    labels.parent.mkdir()
    labels.write_text("0 1 Car 0 0 0 1 2 3 4 1.5 1.6 4 1 1.6 10 0\n0 2 Car 0 0 0 1 2\n")
    with pytest.raises(KittiFormatError, match=r"label_02/0003.txt:2: expected 17 or 18 columns"):
        kitti.read_tracking_labels(labels)


def test_unreadable_png_is_named(tmp_path):
    _tiny_sequence(tmp_path)
    bad = tmp_path / "image_03" / "0003" / "000001.png"
    bad.write_bytes(b"not a png at all")
    seq = kitti.TrackingSequence.open(tmp_path, "0003")
    left, right = seq.read_stereo(0)
    assert left.shape == (8, 12, 3)
    with pytest.raises(KittiFormatError, match=r"image_03/0003/000001.png: unreadable image"):
        seq.read_stereo(1)


# --------------------------------------------------------------- bad input files (issue #35)
BINARY = b"\xff\xfe\x00\x01\x80\x81binary\xc3\x28\n"


def _real_calib_copy(kitti_tracking_root, tmp_path):
    calib = tmp_path / "calib" / "0005.txt"
    calib.parent.mkdir(parents=True)
    calib.write_text((kitti_tracking_root / "calib" / "0005.txt").read_text())
    return calib


def test_non_finite_calibration_values_name_file_line_and_field(kitti_tracking_root, tmp_path):
    """A `nan` in the real 0005 calibration (P3's Tx, the value the baseline comes from) used
    to be read, and every frame was then skipped downstream as "P is missing (all zeros)"."""
    calib = _real_calib_copy(kitti_tracking_root, tmp_path)
    lines = calib.read_text().splitlines()
    p3 = lines[3].split()
    assert p3[0] == "P3:"
    p3[4] = "nan"  # P3[0,3]
    lines[3] = " ".join(p3)
    calib.write_text("\n".join(lines) + "\n")
    with pytest.raises(KittiFormatError) as err:
        kitti.read_calib(calib)
    assert str(err.value) == (
        f"{calib}:4: P3[0,3]: non-finite value nan (a calibration holds finite numbers only)"
    )
    lines = (kitti_tracking_root / "calib" / "0005.txt").read_text().splitlines()
    lines[4] = lines[4].replace("9.999421000000e-01", "inf")  # R_rect[1,1]
    calib.write_text("\n".join(lines) + "\n")
    with pytest.raises(KittiFormatError, match=r"0005.txt:5: R_rect\[1,1\]: non-finite value inf"):
        kitti.read_calib(calib)


def test_a_calibration_without_a_stereo_baseline_is_named(kitti_tracking_root, tmp_path):
    calib_file = _real_calib_copy(kitti_tracking_root, tmp_path)
    calib = kitti.read_calib(calib_file)
    kitti.check_stereo_calibration(calib, calib_file)  # the real one passes
    for p3 in (calib.P2, calib.P2 + np.array([[0, 0, 0, 100.0], [0] * 4, [0] * 4])):
        bad = kitti.Calibration(calib.P0, calib.P1, calib.P2, p3)
        with pytest.raises(KittiFormatError, match=rf"^{calib_file}: P2\[0,3\] - P3\[0,3\] = "):
            kitti.check_stereo_calibration(bad, calib_file)


@pytest.mark.parametrize("kind", ["calib", "labels", "object labels"])
def test_binary_files_are_one_line_naming_the_file(tmp_path, kind):
    path = tmp_path / "0003.txt"
    path.write_bytes(BINARY)
    read = {
        "calib": kitti.read_calib,
        "labels": kitti.read_tracking_labels,
        "object labels": kitti.read_object_labels,
    }[kind]
    with pytest.raises(KittiFormatError) as err:
        read(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: not a text file (byte 0xff at offset 0 is not UTF-8)")
    assert "\n" not in msg


ROW = "Car 0 0 -1.5 600 170 700 230 1.5 1.6 3.9 1.0 1.7 10 -1.57"


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        ([f"0 1 {ROW}", f"1 1 {ROW.replace('600', 'nan')}"], r":2: bbox x1: non-finite value nan"),
        ([f"0 1 {ROW} inf"], r":1: score: non-finite value inf"),
        ([f"0 1 {ROW.replace('-1.57', '-inf')}"], r":1: rotation_y: non-finite value -inf"),
        ([f"0 1 {ROW}", f"-1 2 {ROW}"], r":2: frame: -1 is negative"),
        ([f"0 -2 {ROW}"], r":1: track id: -2"),
        (
            [f"0 1 {ROW}", f"0 2 {ROW}", f"1 1 {ROW}", f"1 1 {ROW}"],
            r":4: track id 1 appears twice in frame 1 \(also on line 3\)",
        ),
    ],
)
def test_label_and_result_rows_that_cannot_be_scored_are_named(tmp_path, rows, message):
    """NaN boxes, frame -1 and one track twice in a frame used to be accepted by `evaluate
    tracking` (MOTA of a run that is not one); KITTI's files never hold them."""
    path = tmp_path / "0005.txt"
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(KittiFormatError, match=rf"^{path}{message}"):
        kitti.read_tracking_labels(path)


def test_dontcare_rows_may_share_id_minus_one_and_real_labels_pass(kitti_tracking_root, tmp_path):
    path = tmp_path / "0005.txt"
    dc = "DontCare -1 -1 -10 10 10 20 20 -1 -1 -1 -1000 -1000 -1000 -10"
    path.write_text(f"0 -1 {dc}\n0 -1 {dc}\n0 3 {ROW}\n")
    assert len(kitti.read_tracking_labels(path)[0]) == 3
    for f in sorted((kitti_tracking_root / "label_02").glob("*.txt")):
        kitti.read_tracking_labels(f)  # every real label file still reads
    obj = tmp_path / "000001.txt"
    obj.write_text(f"{ROW.replace('600', 'nan')}\n")
    with pytest.raises(KittiFormatError, match=rf"^{obj}:1: bbox x1: non-finite value nan"):
        kitti.read_object_labels(obj)
