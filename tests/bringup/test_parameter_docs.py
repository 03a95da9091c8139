"""Issue #40: config/pipeline.params.yaml and docs/parameters.md are generated from the parameter
dataclasses (tracking_bringup.parameter_docs); the committed files are what it writes, with the
graph's own values (GRAPH_VALUES) applied and the meanings read from the fields' comments."""

from __future__ import annotations

import importlib.util
import math
import sys
import textwrap

import pytest
import yaml
from tracking_bringup.environment import PARAMS_FILE
from tracking_bringup.parameter_docs import (
    COMMAND,
    field_meanings,
    node_sections,
    pipeline_yaml,
    stale,
    yaml_value,
)
from tracking_bringup.parameters import (
    GRAPH_VALUES,
    LAUNCH_PROFILES,
    LAUNCHER_SET,
    NODE_PARAMETERS,
    default,
    graph_values,
)
from vehicle_common.node_parameters import check_value

from tracking_bringup import parameter_docs


def test_the_committed_files_are_what_the_generator_writes():
    assert not stale(), f"not up to date: {[str(p) for p in stale()]}; run {COMMAND}"


def test_the_check_finds_an_edited_value(tmp_path, monkeypatch):
    """A value changed by hand in the committed file is found (as the test above would)."""
    edited = tmp_path / "pipeline.params.yaml"
    text = pipeline_yaml()
    edited.write_text(text.replace("    stationary_prior: 0.8 ", "    stationary_prior: 0.7 ", 1))
    assert edited.read_text() != text
    monkeypatch.setattr(parameter_docs, "PARAMS_FILE", edited)
    monkeypatch.setattr(parameter_docs, "DOCS_FILE", tmp_path / "parameters.md")
    (tmp_path / "parameters.md").write_text(parameter_docs.parameters_markdown())
    assert stale() == [edited]
    assert parameter_docs.main(["--check"]) == 1


def _same(a, b) -> bool:
    if isinstance(a, (list, tuple)):
        return isinstance(b, (list, tuple)) and len(a) == len(b) and all(map(_same, a, b))
    return type(a) is type(b) and a == b


def test_the_file_holds_every_parameter_at_its_graph_value():
    data = yaml.safe_load(PARAMS_FILE.read_text())
    for node in NODE_PARAMETERS:
        section = data[node]["ros__parameters"]
        expected = graph_values(node)
        assert set(section) == set(expected), node
        for name, value in expected.items():
            assert _same(section[name], value), f"{node}.{name}: {section[name]!r} != {value!r}"
        assert not set(section) & set(LAUNCHER_SET.get(node, {})), node
    assert data["stereo_tracking_launch"]["ros__parameters"] == LAUNCH_PROFILES


def test_graph_values_differ_from_the_defaults_are_accepted_and_say_why():
    for node, values in GRAPH_VALUES.items():
        for name, (value, why) in values.items():
            rule = next(p.rule for _, ps in node_sections(node) for p in ps if p.name == name)
            assert not _same(value, default(node, name)), f"{node}.{name}: the node's default"
            check_value(f"{node}.{name}", value, default(node, name), rule)
            assert len(why) > 10, f"{node}.{name}: no reason"


def test_every_parameter_has_a_meaning():
    missing = [
        f"{node}.{p.name} ({cls.__name__})"
        for node in NODE_PARAMETERS
        for cls, params in node_sections(node)
        for p in params
        if not p.meaning
    ]
    assert not missing, "parameters without a comment in their dataclass: " + ", ".join(missing)


def test_meanings_are_read_from_the_fields_comments(tmp_path, monkeypatch):
    source = textwrap.dedent(
        '''
        from dataclasses import dataclass

        @dataclass
        class Sample:
            """Doc."""

            # the first field, above
            first: int = 1
            own: int = 2  # its own comment,
            # continued below it
            second_own: int = 3  # the next one's own
            # above a field without its own
            plain: int = 4
            trailing: float = 5.0  # a trailing one

            # a group comment after a blank line:
            grouped: int = 6  # the field's own
            bare: int = 7
            last: bool = False  # the last one,
            # continued

            def method(self):
                pass
        '''
    )
    path = tmp_path / "sample_parameters.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("sample_parameters", path)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "sample_parameters", module)
    spec.loader.exec_module(module)
    assert field_meanings(module.Sample) == {
        "first": "the first field, above",
        "own": "its own comment, continued below it",
        "second_own": "the next one's own",
        "plain": "above a field without its own",
        "trailing": "a trailing one",
        "grouped": "a group comment after a blank line: the field's own",
        "bare": "",
        "last": "the last one, continued",
    }


@pytest.mark.parametrize(
    "value",
    [True, 0, -1, 0.3, 1e-05, -2.5e-12, math.inf, -math.inf, "0005", 'a "b"', "", [1.5, 2.0], []],
)
def test_values_read_back_as_written(value):
    read = yaml.safe_load(f"x: {yaml_value(value)}")["x"]
    assert _same(read, value)
