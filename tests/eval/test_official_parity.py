"""The evaluator against the official tools (issue #25): the devkit's k/40 precision booking,
the server code's minimum-height rule, `evaluate detection`, and `evaluate tracking
--similarity iou3d` giving a 3D-IoU HOTA. The last tests reproduce, through the CLI, the official
scores that ../shared/eval_parity stores (KITTI object devkit server code, tracking devkit,
TrackEval); they skip without ../shared."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from eval_node.cli import main as evaluate_main
from eval_node.detection_metrics import precision_recall
from eval_node.tracking_metrics import evaluate_tracking
from vehicle_common.kitti import KittiObject, format_row, write_tracking_labels


def _car(x1=100.0, h=50.0, score=None, loc=(0.0, 1.6, 20.0), dims=(1.5, 1.6, 4.0), frame=0, tid=-1):
    return KittiObject(
        type="Car",
        truncated=0.0,
        occluded=0,
        alpha=0.0,
        bbox=(x1, 100.0, x1 + 100.0, 100.0 + h),
        dimensions=dims,
        location=loc,
        rotation_y=0.0,
        score=score,
        frame=frame,
        track_id=tid,
    )


# Two cars (one per frame) found at scores 0.9 and 0.8, a false positive at 0.85 in between.
# Thresholds: 0.9 (recall 0.5, precision 1) and 0.8 (recall 1, precision 2/3).
GT = {0: [_car()], 1: [_car()]}
PRED = {0: [_car(score=0.9), _car(x1=400.0, score=0.85)], 1: [_car(score=0.8)]}


def test_kitti_interpolation_books_threshold_k_at_recall_k_over_40():
    pr = precision_recall(GT, PRED, criterion="iou2d", threshold=0.7, difficulty="easy")
    # devkit: precision[0] = max(1, 2/3), precision[1] = 2/3, precision[2..40] = 0
    assert pr.precision[:3].tolist() == pytest.approx([1.0, 2 / 3, 0.0])
    assert pr.ap_r40 == pytest.approx((2 / 3) / 40)
    assert pr.ap_r11 == pytest.approx(1 / 11)
    # the named option places each operating point at its actual recall
    rec = precision_recall(
        GT, PRED, criterion="iou2d", threshold=0.7, difficulty="easy", interpolation="recall"
    )
    assert rec.ap_r40 == pytest.approx((20 * 1.0 + 20 * 2 / 3) / 40)
    # every curve also gives that figure (what results.json and the report set beside AP|R40)
    assert pr.ap_actual_recall == pytest.approx(rec.ap_r40)
    assert rec.ap_actual_recall == pytest.approx(rec.ap_r40)
    with pytest.raises(ValueError, match="interpolation"):
        precision_recall(GT, PRED, interpolation="voc")


def _write_object_files(folder: Path, frames: dict) -> None:
    folder.mkdir(parents=True)
    for k, objs in frames.items():
        (folder / f"{k:06d}.txt").write_text(
            "".join(format_row(o, tracking=False) + "\n" for o in objs)
        )


def _detection_json(tmp_path: Path, labels: Path | None = None) -> dict:
    """``evaluate detection`` on ``tmp_path/res`` against ``labels`` (default label_2)."""
    out = tmp_path / "d.json"
    labels = labels or tmp_path / "label_2"
    args = ["detection", "--results", str(tmp_path / "res"), "--labels", str(labels)]
    assert evaluate_main([*args, "--json", str(out)]) == 0
    return json.loads(out.read_text())


def test_evaluate_detection_cli_json_and_table(tmp_path, capsys):
    _write_object_files(
        tmp_path / "label_2", {k: [o.with_(score=None) for o in v] for k, v in GT.items()}
    )
    _write_object_files(tmp_path / "res", PRED)
    res = _detection_json(tmp_path)
    assert set(res["detections_2d"]) == {"0.7", "0.5"}
    for t in ("0.7", "0.5"):
        row = res["detections_2d"][t]
        assert row["easy"] == pytest.approx((2 / 3) / 40)  # AP|R40, KITTI devkit booking
        assert row["easy_r11"] == pytest.approx(1 / 11)
        assert row["easy_num_gt"] == 2
    # the rows carry 3D boxes: the centre-distance AP is there too
    assert res["detections_3d"]["1.5"]["moderate"] == pytest.approx((2 / 3) / 40)
    printed = capsys.readouterr().out
    assert "2D AP|R40 @ IoU 0.7" in printed and "KITTI devkit interpolation" in printed


def test_evaluate_detection_2d_only_rows_have_no_3d_ap(tmp_path):
    flat = {k: [o.with_(dimensions=(-1.0, -1.0, -1.0), location=(-1000.0,) * 3) for o in v]
            for k, v in PRED.items()}  # fmt: skip
    _write_object_files(tmp_path / "label_2", GT)
    _write_object_files(tmp_path / "res", flat)
    assert "detections_3d" not in _detection_json(tmp_path)


def _cli(*args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "eval_node.cli", *map(str, args)], capture_output=True, text=True
    )


@pytest.mark.parametrize("case", ["malformed", "no_label", "empty", "no_results_dir"])
def test_evaluate_detection_bad_input_one_line_exit_2(tmp_path, case):
    _write_object_files(tmp_path / "label_2", GT)
    res = tmp_path / "res"
    _write_object_files(res, PRED)
    expect = str(res)
    if case == "malformed":
        (res / "000001.txt").write_text("Car -1 -1 0 1 2 3\n")
        expect = f"{res / '000001.txt'}:1"
    elif case == "no_label":
        (res / "000007.txt").write_text("")
        expect = str(tmp_path / "label_2" / "000007.txt")
    elif case == "empty":
        for f in res.glob("*.txt"):
            f.unlink()
    else:
        res = tmp_path / "missing"
        expect = str(res)
    p = _cli("detection", "--results", res, "--labels", tmp_path / "label_2")
    assert p.returncode == 2, p.stderr
    assert p.stderr.count("\n") == 1 and p.stderr.startswith("error: "), p.stderr
    assert expect in p.stderr


def test_evaluate_detection_tracking_label_file(tmp_path):
    """A tracking label file pairs its frame indices with NNNNNN.txt result files."""
    labels = tmp_path / "0000.txt"
    write_tracking_labels(labels, [o.with_(frame=k, track_id=1) for k, v in GT.items() for o in v])
    _write_object_files(tmp_path / "res", PRED)
    assert _detection_json(tmp_path, labels)["detections_2d"]["0.7"]["easy_num_gt"] == 2


def test_evaluate_tracking_similarity_applies_to_hota(tmp_path, capsys):
    """--similarity iou3d gives the 3D-IoU HOTA (it printed the 2D one before)."""
    gt_rows, tr_rows = [], []
    for f in range(10):
        gt_rows.append(_car(frame=f, tid=1))
        # same 2D box, 3D box 0.6 m off in depth: 2D IoU 1, 3D IoU about 0.74
        tr_rows.append(_car(frame=f, tid=7, loc=(0.0, 1.6, 20.6), score=1.0))
    (tmp_path / "labels").mkdir()
    (tmp_path / "res").mkdir()
    write_tracking_labels(tmp_path / "labels" / "0000.txt", gt_rows)
    write_tracking_labels(tmp_path / "res" / "0000.txt", tr_rows)
    out = tmp_path / "t.json"
    rc = evaluate_main(
        ["tracking", "--results", str(tmp_path / "res"), "--labels", str(tmp_path / "labels"),
         "--similarity", "iou3d", "--json", str(out)]
    )  # fmt: skip
    assert rc == 0
    total = json.loads(out.read_text())["total"]
    gt = {f: [o] for f, o in enumerate(gt_rows)}
    tr = {f: [o] for f, o in enumerate(tr_rows)}
    hota3 = evaluate_tracking(gt, tr, similarity="iou3d", hota_similarity="iou3d")["hota"]
    hota2 = evaluate_tracking(gt, tr, similarity="iou3d", hota_similarity="iou2d")["hota"]
    assert hota2 > hota3 + 0.1
    assert total["hota"] == pytest.approx(hota3)
    assert "3D box IoU" in capsys.readouterr().out


# ----------------------------------------------------------------------------- official scores


@pytest.fixture(scope="module")
def parity(shared_kitti) -> Path:
    root = shared_kitti.parent / "eval_parity"
    if not (root / "README.md").is_file():
        pytest.skip(f"official-score inputs not found at {root} (../shared/eval_parity)")
    return root


def test_detection_equals_official_object_devkit(parity, shared_kitti, tmp_path):
    """KITTI object devkit server code on obj104_detections (shared/eval_parity/README.md)."""
    out = tmp_path / "d.json"
    rc = evaluate_main(
        ["detection", "--results", str(parity / "obj104_detections"), "--labels",
         str(shared_kitti / "object" / "training" / "label_2"), "--json", str(out)]
    )  # fmt: skip
    assert rc == 0
    d2 = json.loads(out.read_text())["detections_2d"]
    official = {
        ("0.7", "r40"): (39.97, 29.14, 26.86),
        ("0.7", "r11"): (41.83, 32.59, 31.02),
        ("0.5", "r40"): (81.08, 69.82, 67.13),
        ("0.5", "r11"): (81.09, 68.67, 67.08),
    }
    for (iou, kind), values in official.items():
        got = [100 * d2[iou][f"{lv}_{kind}"] for lv in ("easy", "moderate", "hard")]
        assert got == pytest.approx(values, abs=0.01), (iou, kind)
    assert [d2["0.7"][f"{lv}_num_gt"] for lv in ("easy", "moderate", "hard")] == [90, 200, 241]


@pytest.mark.parametrize(
    ("similarity", "hota", "mota"), [("iou2d", 72.258, 86.131), ("iou3d", 65.445, 86.042)]
)
def test_tracking_equals_official_tools(
    parity, kitti_tracking_root, tmp_path, similarity, hota, mota
):
    """TrackEval HOTA (2D and 3D IoU) and the tracking devkit's best-threshold MOTA."""
    out = tmp_path / "t.json"
    rc = evaluate_main(
        ["tracking", "--results", str(parity / "pointrcnn_tracks_dev6"), "--labels",
         str(kitti_tracking_root / "label_02"), "--similarity", similarity, "--json", str(out)]
    )  # fmt: skip
    assert rc == 0
    total = json.loads(out.read_text())["total"]
    assert 100 * total["hota"] == pytest.approx(hota, abs=5e-4)
    assert 100 * total["mota"] == pytest.approx(mota, abs=5e-4)


def test_results_table_says_where_the_devkit_caps_ap():
    from eval_node.report import cap_note

    few = {"detections_2d": {"0.5": {"easy_num_gt": 5, "moderate_num_gt": 38, "hard_num_gt": 41}}}
    note = cap_note(few)
    assert "easy 5, moderate 38)" in note and "num_gt / 40" in note
    many = {
        "detections_2d": {"0.5": {"easy_num_gt": 90, "moderate_num_gt": 200, "hard_num_gt": 241}}
    }
    assert cap_note(many) is None


def test_results_table_gives_the_actual_recall_ap_where_the_devkit_caps_it():
    """Two cars found perfectly: the devkit's AP|R40 is 1/40 (capped), the actual-recall AP 1;
    the report's table sets the second beside the first only when fewer than 40 boxes count."""
    from eval_node.bag_evaluation import DISTANCES, IOUS
    from eval_node.detection_metrics import ap_table
    from eval_node.report import table_rows

    perfect = {0: [_car(score=0.9)], 1: [_car(score=0.8)]}
    res = {
        "detections_3d": ap_table(GT, perfect, "centre_distance", DISTANCES),
        "tracks_3d": ap_table(GT, perfect, "centre_distance", DISTANCES),
        "detections_2d": ap_table(GT, perfect, "iou2d", IOUS),
    }
    row = res["tracks_3d"]["1.5"]
    assert row["easy"] == pytest.approx(1 / 40) and row["easy_actual_recall"] == pytest.approx(1)
    _, rows = table_rows(res)
    marked = {r[0]: r[1:] for r in rows if r[0].endswith("actual recall")}
    assert marked["tracks @ 1.5 m, actual recall"][0].strip() == "100.0"
    for table in res.values():  # 40 counted boxes: no cap, no extra rows
        for r in table.values():
            r.update({f"{lv}_num_gt": 40 for lv in ("easy", "moderate", "hard")})
    assert not [r for r in table_rows(res)[1] if r[0].endswith("actual recall")]
