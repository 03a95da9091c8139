"""bench/paired.py: candidate minus base per draw, and the velocity like for like (the rows
both runs matched)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "bench"))
import paired  # noqa: E402


def _run(mota, rows):
    # as `bench_tracker.py real --json` writes it, row lists beside the figures
    fig = {
        "mota_all_rows": mota,
        "velocity_rows_keyed": rows,
        "jitter_rows": [[0.0, 3, 20.0, 0.1, 0.02]],
    }
    return {"camera/tuning": {"kalman": fig}}


BASE = [["0001", 1, 7, 0, 1.0], ["0001", 2, 7, 1, 3.0], ["0002", 1, 4, 0, 2.0]]
# the candidate matched a car the base did not (a hard row: 10 m/s off) and lost another
CAND = [["0001", 1, 7, 0, 0.5], ["0001", 2, 7, 1, 3.0], ["0002", 5, 9, 0, 10.0]]


def test_like_for_like_takes_only_rows_both_runs_matched():
    r = paired.like_for_like(BASE, CAND)
    assert r["all"]["n"] == 2
    assert r["all"]["base"] == pytest.approx(math.sqrt((1.0 + 9.0) / 2))
    assert r["all"]["cand"] == pytest.approx(math.sqrt((0.25 + 9.0) / 2))
    assert r["accelerating"] == {"n": 1, "base": 3.0, "cand": 3.0}


def test_paired_differences_per_draw(tmp_path, capsys):
    files = []
    for name, run in [
        ("b0", _run(80.0, BASE)),
        ("b1", _run(82.0, BASE)),
        ("c0", _run(81.0, CAND)),
        ("c1", _run(81.5, CAND)),
    ]:
        f = tmp_path / f"{name}.json"
        f.write_text(json.dumps(run))
        files.append(str(f))
    res = paired.paired(
        [json.loads(Path(f).read_text()) for f in files[:2]],
        [json.loads(Path(f).read_text()) for f in files[2:]],
    )
    slot = res["camera/tuning"]["kalman"]
    assert slot["mota_all_rows"] == pytest.approx([1.0, -0.5])
    assert "jitter_rows" not in slot
    assert slot["lfl_all_rows"] == [2, 2]
    assert slot["lfl_all_diff"][0] == pytest.approx(math.sqrt(9.25 / 2) - math.sqrt(5.0))
    assert paired.main(["--base", *files[:2], "--cand", *files[2:]]) == 0
    assert "mota_all_rows" in capsys.readouterr().out


def test_unpaired_files_are_one_clear_error(tmp_path, capsys):
    f = tmp_path / "b.json"
    f.write_text(json.dumps(_run(80.0, BASE)))
    assert paired.main(["--base", str(f), str(f), "--cand", str(f)]) == 2
    assert "one candidate per base run" in capsys.readouterr().err
    assert paired.main(["--base", str(tmp_path / "missing.json"), "--cand", str(f)]) == 2
    assert "missing.json" in capsys.readouterr().err
