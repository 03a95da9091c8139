"""Synthetic KITTI generator: layout, determinism, manifest reuse, CLI errors."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from kitti_player_node.synthetic import (
    KITTI_BASELINE,
    KITTI_CX,
    KITTI_CY,
    KITTI_FX,
    generate_sequence,
    main,
)
from vehicle_common.kitti import TrackingSequence

SMALL = {"width": 414, "height": 125}


def _tree_bytes(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes()
        for p in sorted(root.rglob("*"))
        if p.is_file() and p.suffix in (".png", ".txt")
    }


def test_layout_and_readback_full_size(tmp_path):
    root = generate_sequence(tmp_path / "kitti", sequence="0003", frames=3, seed=1)
    seq = TrackingSequence.open(root, "0003")
    assert seq.frame_ids == [0, 1, 2]
    left, right = seq.read_stereo(2)
    assert left.shape == right.shape == (375, 1242, 3)
    assert left.dtype == np.uint8
    assert not np.array_equal(left, right)
    c = seq.calib
    assert c.fx == pytest.approx(KITTI_FX) and c.fy == pytest.approx(KITTI_FX)
    assert c.cx == pytest.approx(KITTI_CX) and c.cy == pytest.approx(KITTI_CY)
    assert c.baseline == pytest.approx(KITTI_BASELINE)
    assert c.P2[0, 3] == pytest.approx(KITTI_FX * 0.06)
    assert c.left_camera_offset[0] == pytest.approx(0.06)
    assert seq.labels is not None
    assert set(seq.labels) <= {0, 1, 2}
    cars = [o for k in seq.frame_ids for o in seq.objects(k) if not o.is_dontcare]
    assert cars, "a default scene shows labelled vehicles"
    assert {o.type for o in cars} <= {"Car", "Van"}
    assert (root / "synthetic_0003.json").is_file()


def test_deterministic_per_seed_and_reused(tmp_path):
    a = generate_sequence(tmp_path / "a", frames=3, seed=5, **SMALL)
    b = generate_sequence(tmp_path / "b", frames=3, seed=5, **SMALL)
    c = generate_sequence(tmp_path / "c", frames=3, seed=6, **SMALL)
    ta, tb, tc = _tree_bytes(a), _tree_bytes(b), _tree_bytes(c)
    assert len(ta) == 3 * 2 + 2
    assert ta == tb
    differing = [k for k in ta if k.endswith(".png") and ta[k] != tc[k]]
    assert len(differing) == 6
    assert ta["label_02/0000.txt"] != tc["label_02/0000.txt"]
    # unchanged settings: nothing is rewritten; changed settings: re-rendered
    png = a / "image_02" / "0000" / "000001.png"
    before = png.stat().st_mtime_ns
    generate_sequence(a, frames=3, seed=5, **SMALL)
    assert png.stat().st_mtime_ns == before
    generate_sequence(a, frames=2, seed=6, **SMALL)
    assert TrackingSequence.open(a, "0000").frame_ids == [0, 1]
    assert _tree_bytes(a)["image_02/0000/000001.png"] != ta["image_02/0000/000001.png"]


def test_cli_writes_sequence(tmp_path):
    exe = Path(sys.executable).parent / "kitti_synth"
    cmd = [str(exe)] if exe.is_file() else [sys.executable, "-m", "kitti_player_node.synthetic"]
    out = tmp_path / "cli"
    args = ["--output", str(out), "--sequence", "7", "--frames", "2", "--seed", "3"]
    args += ["--vehicles", "4", "--width", "320", "--height", "100", "--quiet"]
    res = subprocess.run(cmd + args, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    seq = TrackingSequence.open(out, "0007")
    assert seq.frame_ids == [0, 1]
    assert seq.read_stereo(1)[0].shape == (100, 320, 3)


@pytest.mark.parametrize(
    "extra, field",
    [
        (["--frames", "0"], "--frames"),
        (["--vehicles", "-1"], "--vehicles"),
        (["--width", "8"], "--width"),
        (["--frames", "abc"], "arguments"),
        (["--sequence", "a/b"], "--sequence"),
    ],
)
def test_cli_bad_arguments(tmp_path, capsys, extra, field):
    assert main(["--output", str(tmp_path / "o"), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith(f"error: {field}")


def test_cli_unwritable_output(tmp_path, capsys):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    assert main(["--output", str(blocker / "sub"), "--frames", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {blocker / 'sub'}")
    assert main(["--output", str(blocker), "--frames", "1"]) == 2
    assert "exists and is not a folder" in capsys.readouterr().err
