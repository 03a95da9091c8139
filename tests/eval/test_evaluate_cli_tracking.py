"""`evaluate tracking` on the real KITTI labels scored against themselves."""

from __future__ import annotations

import json
import subprocess
import sys


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
