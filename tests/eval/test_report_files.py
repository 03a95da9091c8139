"""write_report on a synthetic recorded run with images: every file is written and non-empty;
the filter comparison runs the tracker core with each filter."""

from __future__ import annotations

import pytest
from test_evaluate_cli_bag import make_bag  # same folder (pytest puts it on sys.path)


def test_report_files_and_filter_comparison(tmp_path):
    from eval_node.bag_evaluation import evaluate_bag
    from eval_node.report import results_table, write_report
    from PIL import Image

    bag = make_bag(tmp_path / "bag", images=True)
    res = evaluate_bag(bag)
    table = res["filter_comparison"]
    assert set(table) == {"none", "kalman", "particle"}
    for name, row in table.items():
        # perfect detections: every GT box is found, the first frame's by tentative tracks
        # (ranked at half the score with min_hits 2): precision 1 up to recall 1
        assert row["moderate"] == pytest.approx(1.0), name
        assert row["ap_r40"]["moderate"] == pytest.approx(1.0), name
        assert row["fps"] > 0
    files = write_report(res, tmp_path / "report")
    expected = {"md", "html", "gif", "bev", "confusion"}
    expected |= {f"pr_{s}" for s in ("detections_3d", "tracks_3d", "detections_2d")}
    assert set(files) == expected
    for path in files.values():
        assert path.is_file() and path.stat().st_size > 0, path
    assert Image.open(files["gif"]).n_frames == res["frames"]
    md = files["md"].read_text()
    assert "Filter comparison" in md and "overlay.gif" in md
    assert "| tracks @ 1.5 m | 100.0 | 100.0 | 100.0 |" in md
    assert '<img src="bev_trajectories.png"' in files["html"].read_text()
    text = results_table(res)
    assert "kalman" in text and "particle" in text
    # the matched cars' jitter in metres beside its ratio (tracks / labels)
    m = res["velocity"]["stability"]["matched"]
    row = next(ln for ln in text.splitlines() if "position jitter, matched cars" in ln)
    pred, gt = (f"{m[k]:.3f}" if m["n"] else "n/a" for k in ("pred_rms_m", "gt_rms_m"))
    assert row.split()[-3:] == [pred, "/", gt]


def test_report_without_images_has_no_gif(tmp_path):
    from eval_node.bag_evaluation import evaluate_bag
    from eval_node.report import write_report

    res = evaluate_bag(make_bag(tmp_path / "bag"), run_filters=False)
    files = write_report(res, tmp_path / "report")
    assert "gif" not in files and files["md"].stat().st_size > 0
    assert "Filter comparison" not in files["md"].read_text()
