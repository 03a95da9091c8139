"""``stereo_tracking_launch`` and ``bag_player`` options that cannot be used: one line naming the
option and exit code 2 before anything starts (issue #42: --log-dir that could not be created
was a traceback, --stall-timeout 0 / -5 / nan and bag_player --rate -1 / nan / inf were
accepted, --nodes , hung forever, --ready-timeout -1 exited 1)."""

from __future__ import annotations

import pytest


def _launch(monkeypatch, tmp_path, *args: str) -> tuple[int, list]:
    """main(ARGS) with the graph not started: (exit code, the run_graph calls)."""
    from tracking_bringup import launcher

    calls = []
    monkeypatch.setattr(launcher, "run_graph", lambda *a, **k: calls.append((a, k)) or 0)
    argv = list(args) if "--log-dir" in args else ["--log-dir", str(tmp_path / "logs"), *args]
    return launcher.main(argv), calls


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--stall-timeout", "0"], "--stall-timeout 0: must be >= 1 (seconds; every node"),
        (["--stall-timeout", "-5"], "--stall-timeout -5: must be >= 1"),
        (["--stall-timeout", "nan"], "--stall-timeout nan: expected a finite number"),
        (["--ready-timeout", "-1"], "--ready-timeout -1: must be > 0"),
        (["--ready-timeout", "inf"], "--ready-timeout inf: expected a finite number"),
        (["--nodes", ","], "--nodes ',': no node named (comma-separated names of kitti_player"),
        (["--nodes", " "], "--nodes ' ': no node named"),
        (["--graph", ","], "--graph ',': no node named"),
    ],
)
def test_bad_launcher_option_is_one_line_and_exit_2(monkeypatch, tmp_path, capsys, args, message):
    code, calls = _launch(monkeypatch, tmp_path, *args)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not calls
    assert len(err) == 1 and err[0].startswith(f"error: {message}"), err


@pytest.mark.parametrize("blocker", ["file", "file/below"])
def test_log_dir_that_cannot_be_created_is_one_line(monkeypatch, tmp_path, capsys, blocker):
    """A --log-dir where a file is in the way (or below a file): one line, exit 2 (before: a
    FileExistsError / NotADirectoryError traceback)."""
    (tmp_path / "file").write_text("x")
    log_dir = tmp_path / blocker
    code, calls = _launch(monkeypatch, tmp_path, "--log-dir", str(log_dir))
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not calls
    assert len(err) == 1 and err[0].startswith(f"error: --log-dir {log_dir}: cannot create"), err


def test_good_options_still_start(monkeypatch, tmp_path):
    code, calls = _launch(
        monkeypatch,
        tmp_path,
        "--stall-timeout",
        "1",
        "--ready-timeout",
        "0.5",
        "--nodes",
        "kitti_player,",
    )
    assert code == 0 and len(calls) == 1
    assert calls[0][1]["stall_timeout"] == 1.0 and calls[0][1]["ready_timeout"] == 0.5
    assert [p.name for p in calls[0][0][0]] == ["kitti_player"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--rate", "-1"], "--rate -1: must be >= 0 (speed factor, 0 = fast as possible)"),
        (["--rate", "nan"], "--rate nan: expected a finite number"),
        (["--rate", "inf"], "--rate inf: expected a finite number"),
        (["--wait-timeout", "-2"], "--wait-timeout -2: must be >= 0"),
        (["--discovery-time", "nan"], "--discovery-time nan: expected a finite number"),
        (["--ack-timeout", "-1"], "--ack-timeout -1: must be >= 0"),
        (["--sync-tolerance", "-0.1"], "--sync-tolerance -0.1: must be >= 0"),
        (["--wait-for-subscribers", "-1"], "--wait-for-subscribers -1: must be >= 0"),
    ],
)
def test_bad_bag_player_option_is_one_line_and_exit_2(tmp_path, capsys, args, message):
    from kitti_player_node.bag_player import main

    assert main([str(tmp_path / "no_bag"), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {message}"), err


@pytest.mark.parametrize(
    "player",
    [
        ["-p", "kitti_player.rate:=0.0", "-p", "kitti_player.lockstep:=false"],
        ["-p", "kitti_player.rate_multiplier:=0", "-p", "kitti_player.lockstep:=false"],
    ],
)
def test_unpaced_player_without_lockstep_is_refused(monkeypatch, tmp_path, capsys, player):
    """``kitti_player.rate:=0.0 lockstep:=false`` published 16 frames of 0005 as fast as it
    could and the detector took 8: the others were overwritten in its KEEP_LAST input queue,
    counted by no node (issue #42). The launcher refuses it in one line, exit 2; unpaced in
    lockstep (as fast as the graph allows) and paced without lockstep still start."""
    code, calls = _launch(monkeypatch, tmp_path, *player)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not calls
    assert len(err) == 1 and "(unpaced) without lockstep" in err[0], err
    assert "set kitti_player.lockstep:=true" in err[0]
    for ok in (
        ["-p", "kitti_player.rate:=0.0", "-p", "kitti_player.lockstep:=true"],
        ["-p", "kitti_player.rate:=20.0", "-p", "kitti_player.lockstep:=false"],
    ):
        code, calls = _launch(monkeypatch, tmp_path / ok[1], *ok)
        assert code == 0 and len(calls) == 1
