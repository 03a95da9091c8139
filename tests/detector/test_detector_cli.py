"""The detector_train / detector_anchors CLIs on a tiny generated sequence, and their errors."""

from __future__ import annotations

import json

import torch
from detector_node.anchors import main as anchors_main
from detector_node.checkpoint import load_checkpoint
from detector_node.train import main as train_main


def test_train_cli_writes_loadable_checkpoints_and_resumes(tmp_path, capsys):
    from kitti_player_node.synthetic import generate_sequence

    root = tmp_path / "data"
    generate_sequence(root, "0003", 4, seed=3)
    out = tmp_path / "run"
    common = [
        "--train",
        f"{root}:0003",
        "--val",
        str(root),
        "--output",
        str(out),
        "--input-width",
        "256",
        "--input-height",
        "96",
        "--no-progress",
        "--warmup-epochs",
        "1",
        "--final-epochs",
        "0",
        "--batch-size",
        "2",
    ]
    assert train_main([*common, "--epochs", "1"]) == 0
    assert train_main([*common, "--epochs", "2", "--resume", str(out / "last.pt")]) == 0
    log = [json.loads(line) for line in (out / "train_log.jsonl").read_text().splitlines()]
    assert [e["epoch"] for e in log] == [1, 2]
    assert log[0]["lr"] == 1e-4 and log[1]["lr"] == 1e-3
    assert 0.0 <= log[1]["ap50"] <= 1.0
    raw = torch.load(out / "last.pt", weights_only=True)
    assert raw["epoch"] == 1 and "optimizer" in raw
    model, _ = load_checkpoint(out / "best.pt")
    assert (model.config.input_width, model.config.input_height) == (256, 96)
    assert len(model.config.anchors) == 5
    capsys.readouterr()
    assert (
        anchors_main(["--train", str(root), "-k", "3", "--output", str(tmp_path / "a.json")]) == 0
    )
    printed = json.loads(capsys.readouterr().out)
    assert len(printed["anchors"]) == 3 and printed["boxes"] > 3
    assert json.loads((tmp_path / "a.json").read_text())["anchors"] == printed["anchors"]


def test_cli_bad_input_is_one_line_exit_2(tmp_path, capsys):
    assert train_main(["--train", str(tmp_path / "missing"), "--output", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "missing" in err[0]
    assert anchors_main(["--train", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("error: ")
