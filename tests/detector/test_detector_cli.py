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


def test_object_layout_source_and_dontcare(tmp_path):
    import math

    import numpy as np
    from detector_node.dataset import frames_from_source, load_sample
    from vehicle_common.kitti import KittiObject, write_object_labels, write_png

    img = np.zeros((375, 1242, 3), np.uint8)
    write_png(tmp_path / "image_2" / "000007.png", img)
    write_object_labels(
        tmp_path / "label_2" / "000007.txt",
        [
            KittiObject("Car", alpha=math.radians(88), bbox=(100.0, 150.0, 300.0, 250.0)),
            KittiObject("Van", alpha=math.radians(-44), bbox=(400.0, 150.0, 500.0, 250.0)),
            KittiObject("Cyclist", alpha=0.0, bbox=(600.0, 150.0, 650.0, 250.0)),
            KittiObject("DontCare", bbox=(700.0, 100.0, 800.0, 200.0)),
        ],
    )
    refs = frames_from_source(str(tmp_path))
    assert [r.name for r in refs] == [f"{tmp_path.name}/000007"]
    s = load_sample(refs[0], 640, 192, ("Car", "Van"))
    sx, sy = 640 / 1242, 192 / 375
    assert np.allclose(
        s.boxes,
        [[100 * sx, 150 * sy, 300 * sx, 250 * sy], [400 * sx, 150 * sy, 500 * sx, 250 * sy]],
        atol=1e-3,
    )
    assert s.bins.tolist() == [2, 3]
    assert np.allclose(s.dontcare, [[700 * sx, 100 * sy, 800 * sx, 200 * sy]], atol=1e-3)
    assert s.image.shape == (192, 640, 3)
    cars_only = load_sample(refs[0], 640, 192, ("Car",))
    assert len(cars_only.boxes) == 1


def test_train_cli_mixes_real_partial_synthetic_and_starts_from_init(tmp_path, capsys):
    import numpy as np
    from detector_node.model import YoloV2Passthrough, preset
    from kitti_player_node.synthetic import generate_sequence
    from vehicle_common.kitti import KittiObject, write_object_labels, write_png

    root = tmp_path / "data"
    generate_sequence(root, "0001", 3, seed=1)
    crops = tmp_path / "crops"
    rng = np.random.default_rng(0)
    write_png(crops / "image_2" / "000101.png", rng.integers(0, 255, (96, 96, 3), np.uint8))
    write_object_labels(
        crops / "label_2" / "000101.txt", [KittiObject("Car", bbox=(10.0, 20.0, 60.0, 50.0))]
    )
    init = tmp_path / "init.pt"
    from detector_node.checkpoint import save_checkpoint

    save_checkpoint(init, YoloV2Passthrough(preset("tiny", input_width=256, input_height=96)))
    out = tmp_path / "run"
    args = [
        "--train",
        f"{root}:0001@2",
        "--partial",
        f"{crops}@1",
        "--synthetic",
        f"{root}:0001@0.5",
        "--init",
        str(init),
        "--output",
        str(out),
        "--input-width",
        "256",
        "--input-height",
        "96",
        "--epochs",
        "1",
        "--epoch-samples",
        "4",
        "--batch-size",
        "2",
        "--no-progress",
    ]
    assert train_main(args) == 0
    printed = capsys.readouterr().out
    assert f"initialised from {init}" in printed
    # the three kinds, sampled by weight 2 : 1 : 0.5
    for kind, prob in (("real", 2 / 3.5), ("partial", 1 / 3.5), ("synthetic", 0.5 / 3.5)):
        assert f"({kind}, " in printed and f"p={prob:.2f})" in printed, printed
    model, state = load_checkpoint(out / "final.pt")
    assert state["epoch"] == 0 and len(model.config.anchors) == 5
    bad = [a if a != f"{crops}@1" else f"{crops}@many" for a in args]
    assert train_main(bad) == 2
