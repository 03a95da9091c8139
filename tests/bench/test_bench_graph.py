"""bench/bench_graph.py: a bad -p override is one line and exit 2, before any node starts."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_a_wrong_node_name_in_an_override_is_one_line_and_exit_2():
    run = subprocess.run(
        [sys.executable, str(REPO / "bench" / "bench_graph.py"), "--no-offline", "--no-cpu"]
        + ["--windows", "1", "-p", "detector.score_threshold:=0.5"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert lines[-1].startswith("error: bad parameter override 'detector.score_threshold:=0.5'")
    assert "did you mean vehicle_detector?" in lines[-1]
    assert "Traceback" not in run.stderr and "[bench]" not in run.stderr
