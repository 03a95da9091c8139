"""`evaluate tracking` on the real KITTI labels scored against themselves; result, label and
output files it cannot use give one line and exit code 2."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


def test_evaluate_tracking_labels_vs_themselves(kitti_tracking_root, tmp_path):
    labels = kitti_tracking_root / "label_02"
    out = tmp_path / "m.json"
    p = subprocess.run(
        [sys.executable, "-m", "eval_node.cli", "tracking", "--results", str(labels),
         "--labels", str(labels), "--seqs", "0005", "0006", "--json", str(out)],
        capture_output=True, text=True,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    res = json.loads(out.read_text())
    total = res["total"]
    assert total["mota"] == 1.0 and total["idsw"] == 0 and total["fp"] == 0
    assert total["tp"] > 0 and set(res["per_sequence"]) == {"0005", "0006"}
    assert "total" in p.stdout and "100.0" in p.stdout


def test_evaluate_tracking_missing_results_exit_2(kitti_tracking_root, tmp_path):
    p = subprocess.run(
        [sys.executable, "-m", "eval_node.cli", "tracking", "--results", str(tmp_path / "none"),
         "--labels", str(kitti_tracking_root / "label_02")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert p.returncode == 2
    assert p.stderr.count("\n") == 1 and p.stderr.startswith("error: ")
    assert str(tmp_path / "none") in p.stderr


def _results_with(labels_dir, tmp_path, change):
    """A results folder holding 0005's real labels (as perfect results) changed by ``change``
    (a function of the list of lines)."""
    res = tmp_path / "results"
    res.mkdir()
    lines = (labels_dir / "0005.txt").read_text().splitlines()
    (res / "0005.txt").write_text("\n".join(change(lines)) + "\n")
    return res


def _first_car(lines):
    return next(i for i, line in enumerate(lines) if " Car " in line)


def _nan_box(lines):
    i = _first_car(lines)
    t = lines[i].split()
    t[6] = "nan"  # bbox x1
    return [*lines[:i], " ".join(t), *lines[i + 1 :]]


def _swapped(lines, a: int, b: int):
    """The first car's row with columns ``a`` and ``b`` exchanged (an inverted box)."""
    i = _first_car(lines)
    t = lines[i].split()
    t[a], t[b] = t[b], t[a]
    return [*lines[:i], " ".join(t), *lines[i + 1 :]]


def _frame_minus_one(lines):
    i = _first_car(lines)
    return [*lines, " ".join(["-1", *lines[i].split()[1:]])]


def _duplicate_id(lines):
    i = _first_car(lines)
    return [*lines[: i + 1], lines[i], *lines[i + 1 :]]


@pytest.mark.parametrize(
    ("change", "where"),
    [
        (_nan_box, "bbox x1: non-finite value nan"),
        (_frame_minus_one, "frame: -1 is negative"),
        (_duplicate_id, "appears twice in frame"),
        (lambda lines: _swapped(lines, 6, 8), "bbox: inverted box (x2 "),  # x1 <-> x2
        (lambda lines: _swapped(lines, 7, 9), "bbox: inverted box (y2 "),  # y1 <-> y2
    ],
)
def test_results_that_cannot_be_scored_exit_2_naming_file_and_line(
    kitti_tracking_root, tmp_path, capsys, change, where
):
    """These results were scored with exit code 0 (NaN boxes, frame -1, one track id twice in
    a frame, an inverted box: issue #42); now one line names the file and line."""
    from eval_node.cli import main

    labels = kitti_tracking_root / "label_02"
    res = _results_with(labels, tmp_path, change)
    rc = main(["tracking", "--results", str(res), "--labels", str(labels), "--seqs", "0005"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith(f"error: {res / '0005.txt'}:") and where in err[0], err


def test_binary_results_labels_and_detections_exit_2(kitti_tracking_root, tmp_path, capsys):
    from eval_node.cli import main

    labels = kitti_tracking_root / "label_02"
    binary = b"\xff\xfe\x00\x80 not text"
    res = tmp_path / "res"
    res.mkdir()
    (res / "0005.txt").write_bytes(binary)
    bad_labels = tmp_path / "labels"
    bad_labels.mkdir()
    (bad_labels / "0005.txt").write_bytes(binary)
    obj = tmp_path / "obj"
    obj.mkdir()
    (obj / "000001.txt").write_bytes(binary)
    runs = [
        (["tracking", "--results", str(res), "--labels", str(labels)], res / "0005.txt"),
        (["tracking", "--results", str(labels), "--labels", str(bad_labels)], bad_labels),
        (["detection", "--results", str(obj), "--labels", str(labels / "0005.txt")], obj),
    ]
    for argv, named in runs:
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert (
            len(err) == 1 and err[0].startswith(f"error: {named}") and "not a text file" in err[0]
        )


@pytest.mark.parametrize("option", ["--json", "--report"])
def test_unwritable_outputs_exit_2_before_the_evaluation(
    kitti_tracking_root, tmp_path, capsys, option
):
    from eval_node.cli import main

    labels = kitti_tracking_root / "label_02"
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    outs = ["/proc/x/r.json", str(a_file / "r.json")] if option == "--json" else [str(a_file)]
    for out in outs:
        argv = ["tracking", "--results", str(labels), "--labels", str(labels), "--seqs", "0005"]
        if option == "--report":  # only `evaluate bag` writes a report
            argv = ["bag", str(tmp_path / "no_bag")]
        assert main([*argv, option, out]) == 2
        cap = capsys.readouterr()
        err = cap.err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"error: {out}: "), err
        assert cap.out == ""  # refused before the evaluation, not after it


def test_detection_results_named_by_a_negative_frame_are_refused(
    kitti_tracking_root, tmp_path, capsys
):
    """`evaluate detection` pairs result files with a tracking label file by their frame
    number: '-00001.txt' (frame -1) was read as frame -1 and paired with nothing."""
    from eval_node.cli import main

    res = tmp_path / "res"
    res.mkdir()
    (res / "-00001.txt").write_text(
        "Car 0 0 -1.5 600 170 700 230 -1 -1 -1 -1000 -1000 -1000 -10 0.9\n"
    )
    labels = kitti_tracking_root / "label_02" / "0005.txt"
    assert main(["detection", "--results", str(res), "--labels", str(labels)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"error: {res / '-00001.txt'}: result file names must be frame numbers (NNNNNN.txt) to "
        "pair with a tracking label file"
    ]
