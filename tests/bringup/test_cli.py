"""The command line's checks (tracking_bringup.cli): each refused option is one line; main()
with bad options is in test_launcher_options.py."""

import argparse

import pytest
from tracking_bringup.cli import (
    add_params_arguments,
    check_arguments,
    make_log_dir,
    parameter_layers,
    run_log_dir,
)
from tracking_bringup.environment import PARAMS_FILE


def _args(**over):
    values = dict(
        nodes=None,
        graph=None,
        ready_timeout=60.0,
        stall_timeout=5.0,
        params=None,
        params_replace=False,
    )
    values.update(over)
    return argparse.Namespace(**values)


def test_good_arguments_pass_and_become_the_parameter_layers():
    args = _args()
    assert check_arguments(args) is None
    assert args.params == [PARAMS_FILE]


@pytest.mark.parametrize(
    "over, message",
    [
        (dict(nodes=" , "), "--nodes ' , ': no node named"),
        (dict(graph=","), "--graph ',': no node named"),
        (dict(ready_timeout=0.0), "--ready-timeout"),
        (dict(stall_timeout=0.5), "--stall-timeout"),
        (dict(params="/no/such/file.yaml"), "/no/such/file.yaml"),
    ],
)
def test_each_unusable_option_is_named_in_one_line(over, message):
    problem = check_arguments(_args(**over))
    assert problem is not None and message in problem and "\n" not in problem


def test_params_arguments_and_layers(tmp_path):
    parser = argparse.ArgumentParser()
    add_params_arguments(parser)
    extra = tmp_path / "extra.yaml"
    extra.write_text("{}\n")
    args = parser.parse_args(["--params", str(extra)])
    assert parameter_layers(args) is None
    assert [str(p) for p in args.params] == [str(PARAMS_FILE), str(extra)]
    args = parser.parse_args(["--params", str(extra), "--params-replace"])
    assert parameter_layers(args) is None and [str(p) for p in args.params] == [str(extra)]


def test_log_dir_is_made_or_refused_in_one_line(tmp_path):
    assert run_log_dir(tmp_path).parent == tmp_path
    assert make_log_dir(tmp_path / "a" / "b") is None and (tmp_path / "a" / "b").is_dir()
    (tmp_path / "file").write_text("x")
    problem = make_log_dir(tmp_path / "file")
    assert "a file is in the way" in problem
