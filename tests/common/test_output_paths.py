"""Output files and folders of the command-line tools are checked before the work starts: an
unwritable one is one line naming it (vehicle_common.output_paths), and every tool that writes
results uses the check (issue #35: `detector_offline --output /proc/x` was a traceback)."""

from __future__ import annotations

import pytest
from vehicle_common.kitti import KittiFormatError
from vehicle_common.output_paths import (
    OutputPathError,
    check_output_file,
    make_output_dir,
    os_error_line,
)


def test_folders_are_made_and_unusable_places_named(tmp_path):
    assert make_output_dir(tmp_path / "a" / "b").is_dir()
    a_file = tmp_path / "f"
    a_file.write_text("x")
    cases = [
        (tmp_path / "f", f"{a_file}: exists and is not a folder (needed as output folder)"),
        (a_file / "sub", f"{a_file / 'sub'}: cannot create output folder (Not a directory)"),
        ("/proc/x", "/proc/x: cannot create output folder (No such file or directory)"),
    ]
    for path, message in cases:
        with pytest.raises(OutputPathError) as err:
            make_output_dir(path)
        assert str(err.value) == message
        assert isinstance(err.value, KittiFormatError)  # every CLI's main prints it as one line


def test_output_files_are_checked_with_their_folder(tmp_path):
    assert check_output_file(tmp_path / "new" / "r.json", "the --json file").parent.is_dir()
    with pytest.raises(OutputPathError, match=rf"^{tmp_path}: cannot write the --json file: it "):
        check_output_file(tmp_path, "the --json file")
    with pytest.raises(OutputPathError, match=r"^/proc/x/r.json: cannot write r: /proc/x: cannot"):
        check_output_file("/proc/x/r.json", "r")
    assert os_error_line(OSError(28, "No space left on device", "/x/y")) == (
        "/x/y: No space left on device"
    )


def test_demo_and_training_refuse_an_unwritable_output_at_once(tmp_path, capsys):
    from detector_node.train import main as train
    from tracking_bringup.demo import main as demo

    assert demo(["--output", "/proc/x", "--no-eval"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: /proc/x: cannot create output folder (No such file or directory)"]
    assert train(["--train", str(tmp_path / "missing"), "--output", "/proc/x"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: /proc/x: cannot create output folder (No such file or directory)"]


def test_demo_with_an_unusable_checkpoint_is_one_line(tmp_path, capsys):
    """The demo reads the checkpoint itself for another camera's settings: a missing one was a
    CheckpointError traceback."""
    from tracking_bringup.demo import main as demo

    argv = ["--width", "320", "--height", "100", "--frames", "2", "--data-dir", str(tmp_path)]
    argv += ["--output", str(tmp_path / "out"), "-p", "vehicle_detector.checkpoint:=/x.pt"]
    assert demo(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["error: vehicle_detector.checkpoint: /x.pt: checkpoint not found"]
