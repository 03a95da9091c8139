"""bench/bench_ab3dmot.py: AB3DMOT's result files (tiny input) and its DEV reference figures.

The package ``pure-ab-3d-mot`` is not a project dependency: the tests that run AB3DMOT skip
without it (install: ``.venv/bin/pip install --no-deps pure-ab-3d-mot==2.2.0
association-quality-clavia==0.3.2``); the missing-package message is tested without it.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "bench"))
import bench_ab3dmot as ba  # noqa: E402
from tracker_node.detection_files import read_detection_file  # noqa: E402
from vehicle_common.box3d import projected_bbox  # noqa: E402
from vehicle_common.kitti import read_calib, read_tracking_labels  # noqa: E402

# KITTI tracking sequence 0006's P2 (calib/0006.txt), written with identity R0_rect / Tr
P2 = np.array(
    [
        [721.5377, 0.0, 609.5593, 44.85728],
        [0.0, 721.5377, 172.854, 0.2163791],
        [0, 0, 1, 0.002745884],
    ]
)
HWL = (1.5, 1.6, 3.9)


def _needs_package():
    if importlib.util.find_spec("pure_ab_3d_mot") is None:
        pytest.skip(f"pure-ab-3d-mot not installed ({ba.INSTALL})")


def _write_inputs(tmp: Path) -> tuple[Path, Path]:
    """Detections of 8 frames: car A (x = -3 m, approaching 0.5 m per frame) in every frame;
    car B (z = 10 m, x = 2 m moving right 1.5 m per frame) missed in frames 5 and 7, its box
    wholly right of the image from frame 7 on; a one-frame clutter box in frame 4. Scores:
    A 9.0 + frame, B 5.0 + frame, clutter 1.5. Plus a calib file with sequence 0006's P2."""
    det_dir, calib_dir = tmp / "dets", tmp / "calib"
    det_dir.mkdir(exist_ok=True)
    calib_dir.mkdir(exist_ok=True)
    lines = []

    def row(f, x, z, score):
        x1, y1, x2, y2 = projected_bbox(P2, HWL, (x, 1.7, z), -np.pi / 2, ba.IMAGE_SIZE)
        h, w, l = HWL
        lines.append(
            f"{f},2,{x1:.4f},{y1:.4f},{x2:.4f},{y2:.4f},{score},{h},{w},{l},{x},1.7,{z},"
            f"{-np.pi / 2:.6f},{-np.pi / 2:.6f}"
        )

    for f in range(8):
        row(f, -3.0, 20.0 - 0.5 * f, 9.0 + f)
        if f not in (5, 7):
            row(f, 2.0 + 1.5 * f, 10.0, 5.0 + f)
        if f == 4:
            row(f, -8.0, 12.0, 1.5)
    (det_dir / "0000.txt").write_text("\n".join(lines) + "\n")
    p = " ".join(f"{v:.6e}" for v in P2.ravel())
    eye = "1 0 0 0 1 0 0 0 1"
    tr = "1 0 0 0 0 1 0 0 0 0 1 0"
    (calib_dir / "0000.txt").write_text(
        f"P0: {p}\nP1: {p}\nP2: {p}\nP3: {p}\nR0_rect: {eye}\nTr_velo_to_cam: {tr}\n"
        f"Tr_imu_to_velo: {tr}\n"
    )
    return det_dir, calib_dir


def _run(tmp: Path, box2d: str, settings: str = "2020") -> dict:
    det_dir, calib_dir = _write_inputs(tmp)
    out = tmp / f"out_{box2d}"
    stats = ba.run_ab3dmot(det_dir, calib_dir, out, ["0000"], ba.SETTINGS[settings], box2d)
    assert stats["frames"] == 8
    return read_tracking_labels(out / "0000.txt")


def _by_track(frames: dict) -> dict[int, dict[int, object]]:
    out: dict[int, dict[int, object]] = {}
    for f, objs in frames.items():
        for o in objs:
            out.setdefault(o.track_id, {})[f] = o
    return out


def test_result_rows_projection(tmp_path):
    """Rows as AB3DMOT reports them (min_hits 3, max_age 2, every track in the first 3
    frames), each with its 3D box's projection and its last matched detection's score."""
    _needs_package()
    frames = _run(tmp_path, "projection")
    tracks = _by_track(frames)
    # A and B (ids from 1); the clutter box (id 3) has 1 hit after the first 3 frames: not written
    assert sorted(tracks) == [1, 2]
    a, b = tracks[1], tracks[2]
    assert sorted(a) == list(range(8))
    # B: coasting row in frame 5 (unmatched once < max_age); in frame 7 its predicted box
    # (x = 12.5 m at 10 m) is outside the image: row dropped
    assert sorted(b) == [0, 1, 2, 3, 4, 5, 6]
    for f, o in a.items():
        assert o.score == pytest.approx(9.0 + f)
        assert o.location[2] == pytest.approx(20.0 - 0.5 * f, abs=0.3)
        assert o.bbox == pytest.approx(
            projected_bbox(P2, o.dimensions, o.location, o.rotation_y, ba.IMAGE_SIZE), abs=1e-3
        )
    assert b[5].score == pytest.approx(5.0 + 4)  # coasting: frame 4's detection's score
    assert b[5].location[0] == pytest.approx(9.5, abs=0.5)  # predicted on, not frozen
    assert b[5].bbox == pytest.approx(
        projected_bbox(P2, b[5].dimensions, b[5].location, b[5].rotation_y, ba.IMAGE_SIZE),
        abs=1e-3,
    )


def test_result_rows_detection_and_ours_boxes(tmp_path):
    """``detection``: AB3DMOT's own writer (the last matched detection's 2D box, stale on a
    coasting row); ``ours``: tracker_offline's rule (projection on coasting rows)."""
    _needs_package()
    dets = read_detection_file(_write_inputs(tmp_path)[0] / "0000.txt")
    det_box = {
        (int(f), round(float(x), 3)): tuple(b)
        for f, x, b in zip(dets.frame, dets.location[:, 0], dets.bbox, strict=True)
    }
    own = _by_track(_run(tmp_path, "detection"))
    ours = _by_track(_run(tmp_path, "ours"))
    b_own, b_ours = own[2], ours[2]
    assert b_own[5].bbox == pytest.approx(det_box[(4, 8.0)], abs=1e-3)  # stale: frame 4's box
    assert b_ours[5].bbox == pytest.approx(
        projected_bbox(P2, b_ours[5].dimensions, b_ours[5].location, -np.pi / 2, ba.IMAGE_SIZE),
        abs=1e-2,
    )
    assert b_ours[5].bbox[0] > det_box[(4, 8.0)][0] + 5  # the prediction moved on
    assert 7 in b_own and 7 not in b_ours  # stale box kept / projection outside the image
    for f in range(8):  # matched rows: the detection's box in both
        assert own[1][f].bbox == pytest.approx(det_box[(f, -3.0)], abs=1e-3)
        assert ours[1][f].bbox == pytest.approx(det_box[(f, -3.0)], abs=1e-3)


def test_missing_package_one_line_and_exit_2(monkeypatch, capsys):
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util,
        "find_spec",
        lambda name, *a: None if name == "pure_ab_3d_mot" else real(name, *a),
    )
    assert ba.main(["--only", "DEV"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith("error: pure-ab-3d-mot is not installed")
    assert "pip install --no-deps pure-ab-3d-mot==2.2.0 association-quality-clavia==0.3.2" in err[0]


@pytest.mark.slow
def test_reference_reproduced_on_dev(shared_kitti, tmp_path):
    """AB3DMOT's DEV reference in ../shared/notes/kitti-tracking-eval.md (3D IoU 0.25, best
    threshold: MOTA 83.28, FP 246, FN 511, IDSW 0, FRAG 7) comes out of the later code's KITTI
    Car settings with AB3DMOT's own 2D boxes."""
    _needs_package()
    from eval_node.tracking_metrics import evaluate_tracking_dirs

    dets = shared_kitti / "detections" / "pointrcnn_Car_val"
    calib = shared_kitti / "tracking" / "training" / "calib"
    labels = shared_kitti / "tracking" / "training" / "label_02"
    seqs = ["0001", "0006", "0008", "0010", "0012", "0013"]
    ba.run_ab3dmot(dets, calib, tmp_path, seqs, ba.SETTINGS["2022"], "detection")
    m = evaluate_tracking_dirs(tmp_path, labels, seqs=seqs, similarity="iou3d", hota=False)
    assert ba.reference_check(m["total"]).startswith("reference reproduced"), ba.reference_check(
        m["total"]
    )
    assert round(100 * m["total"]["mota"], 2) == 83.28
    assert (m["total"]["fp"], m["total"]["fn"], m["total"]["idsw"]) == (246, 511, 0)


def test_calib_written_by_the_test_reads_back(tmp_path):
    """The tiny input's calib file parses to the P2 the test projects with."""
    _, calib_dir = _write_inputs(tmp_path)
    np.testing.assert_allclose(read_calib(calib_dir / "0000.txt").P2, P2)
