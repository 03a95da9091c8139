"""The graph's parameter file and the parameter reference, generated from the dataclasses.

``config/pipeline.params.yaml`` (every node's every parameter: the node's default, or the graph's
own value from :data:`tracking_bringup.parameters.GRAPH_VALUES` with its reason) and
``docs/parameters.md`` (one table per node: default, graph value, allowed values, meaning) are
written from the parameter dataclasses that :data:`tracking_bringup.parameters.NODE_PARAMETERS`
lists. A parameter's meaning is the comment of its field in the dataclass: on the field's
line(s) and the comment lines below them, or right above the field (:func:`field_meanings`).

    python -m tracking_bringup.parameter_docs           # write both files
    python -m tracking_bringup.parameter_docs --check   # exit 1 naming a file not up to date

No rclpy (the dataclasses' modules are pure)."""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import io
import json
import math
import re
import sys
import textwrap
import tokenize
from functools import cache
from pathlib import Path

from stereo_depth_node.parameters import SECTIONS as STEREO_SECTIONS

from tracking_bringup.environment import PARAMS_FILE
from tracking_bringup.parameters import (
    GRAPH_VALUES,
    LAUNCH_PROFILES,
    LAUNCHER_SET,
    NODE_PARAMETERS,
)

DOCS_FILE = Path(__file__).resolve().parents[3] / "docs" / "parameters.md"
COMMAND = "python -m tracking_bringup.parameter_docs"
WIDTH = 100  # columns of the YAML file
COMMENT_COLUMN = 37  # where a parameter's comment starts in the YAML file


def _class_fields(tree: ast.Module, cls) -> list[ast.AnnAssign]:
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef) and node.name == cls.__name__:
            names = {f.name for f in dataclasses.fields(cls)}
            return [
                s
                for s in node.body
                if isinstance(s, ast.AnnAssign)
                and isinstance(s.target, ast.Name)
                and s.target.id in names
            ]
    raise LookupError(f"{cls.__name__}: class not found in its source file")


def _comments(source: str) -> dict[int, str]:
    """Line number -> the text of the comment on it."""
    return {
        tok.start[0]: tok.string.lstrip("#").strip()
        for tok in tokenize.generate_tokens(io.StringIO(source).readline)
        if tok.type == tokenize.COMMENT
    }


@cache
def field_meanings(cls) -> dict[str, str]:
    """Field name -> meaning of every field of the dataclass ``cls``, from its source comments:
    the comment lines right above the field, then the comment on its own line(s), continued on
    the comment lines right below them. One block of comment lines between two fields that both
    have a comment of their own continues the first one; otherwise it belongs to the field
    below (a blank line sets a group comment apart from the field before it)."""
    source = Path(inspect.getsourcefile(cls)).read_text()
    lines = source.splitlines()
    comments = _comments(source)

    def comment_only(n: int) -> bool:
        return lines[n - 1].lstrip().startswith("#")

    def run(numbers) -> list[int]:  # the comment-only lines of ``numbers`` up to another line
        out = []
        for n in numbers:
            if not (0 < n <= len(lines)) or not comment_only(n):
                break
            out.append(n)
        return out

    fields = _class_fields(ast.parse(source), cls)
    own = {  # the comments on a field's own lines, then their continuation
        f.target.id: [comments[n] for n in range(f.lineno, f.end_lineno + 1) if n in comments]
        for f in fields
    }
    has_own = {name: bool(text) for name, text in own.items()}
    above = {f.target.id: [] for f in fields}
    for prev, f in zip([None, *fields[:-1]], fields, strict=True):
        name = f.target.id
        upward = sorted(run(range(f.lineno - 1, (prev.end_lineno if prev else 0), -1)))
        if prev is None:
            above[name] = [comments[n] for n in upward]
            continue
        below_prev = run(range(prev.end_lineno + 1, f.lineno))
        if below_prev and below_prev == upward and has_own[name] and has_own[prev.target.id]:
            upward = []  # one block between two commented fields: the first one's continuation
        elif below_prev == upward:
            below_prev = []  # one block: above this field
        if has_own[prev.target.id]:
            own[prev.target.id] += [comments[n] for n in below_prev]
        above[name] = [comments[n] for n in upward]
    if fields and has_own[fields[-1].target.id]:  # the last field's continuation
        last = fields[-1]
        below = run(range(last.end_lineno + 1, len(lines) + 1))
        own[last.target.id] += [comments[n] for n in below]

    def joined(name: str) -> str:
        first, second = " ".join(above[name]), " ".join(own[name])
        if first and second:
            return f"{first}{' ' if first.endswith(':') else '; '}{second}"
        return first or second

    return {name: joined(name) for name in own}


def _rules(cls) -> dict[str, dict]:
    """Field -> allowed values of ``cls``: its ``param`` rules, with the stereo node's extra
    rules for the core dataclasses (stereo_depth_node.parameters.SECTIONS)."""
    rules = {f.name: dict(f.metadata) for f in dataclasses.fields(cls)}
    for _, section_cls, kw in STEREO_SECTIONS:
        if section_cls is cls:
            for name, extra in (kw.get("rules") or {}).items():
                rules.setdefault(name, {}).update(extra)
    return rules


@dataclasses.dataclass(frozen=True)
class Parameter:
    """One parameter of a node as the generated files show it."""

    name: str
    default: object
    meaning: str
    rule: dict
    graph: tuple | None  # (value, why): the graph's own value
    launcher: str | None  # how the launchers set it (then not in the file)


def node_sections(node: str) -> list[tuple[type, list[Parameter]]]:
    """``node``'s parameters, by the dataclass that defines them, in declaration order."""
    out = []
    for cls, skip, rename in NODE_PARAMETERS[node]:
        meanings, rules = field_meanings(cls), _rules(cls)
        params = []
        for f in dataclasses.fields(cls):
            if f.name in skip:
                continue
            name = rename.get(f.name, f.name)
            default = f.default if f.default_factory is dataclasses.MISSING else f.default_factory()
            params.append(
                Parameter(
                    name,
                    default,
                    meanings[f.name],
                    rules.get(f.name, {}),
                    GRAPH_VALUES.get(node, {}).get(name),
                    LAUNCHER_SET.get(node, {}).get(name),
                )
            )
        out.append((cls, params))
    return out


def yaml_value(value) -> str:
    """``value`` as the parameter file writes it (YAML that rcl and PyYAML read alike)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isinf(value):
            return ".inf" if value > 0 else "-.inf"
        text = repr(float(value))
        if "e" in text and "." not in text.split("e")[0]:  # PyYAML reads 1e-05 as a string
            mantissa, exponent = text.split("e")
            text = f"{mantissa}.0e{exponent}"
        return text
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(yaml_value(v) for v in value) + "]"
    raise TypeError(f"{value!r}: no parameter value")


def _summary(cls) -> str:
    """The first paragraph of ``cls``'s docstring on one line, Sphinx roles as code."""
    doc = inspect.getdoc(cls) or ""
    return re.sub(r":\w+:`[~.]*([^`]+)`", r"`\1`", " ".join(doc.split("\n\n")[0].split()))


def _wrap(text: str, indent: str, width: int = WIDTH) -> list[str]:
    return textwrap.wrap(
        text, width, initial_indent=indent + "# ", subsequent_indent=indent + "# "
    ) or [indent + "#"]


def _long_list(key: str, value) -> list[str]:
    """``key`` as one line, or a list too long for one as a flow list over several lines."""
    if len(key) <= WIDTH or not isinstance(value, (list, tuple)):
        return [key]
    head = key[: key.index(": [") + 3]
    lines, line = [], head
    for i, item in enumerate(value):
        text = yaml_value(item) + ("," if i < len(value) - 1 else "]")
        if len(line) + len(text) + 1 > WIDTH and line.strip() != head.strip():
            lines.append(line.rstrip())
            line = " " * len(head)
        line += text + " "
    return [*lines, line.rstrip()]


def _yaml_entry(p: Parameter, indent: str) -> list[str]:
    if p.launcher:
        return _wrap(f"{p.name}: set by the launchers: {p.launcher}. {p.meaning}", indent)
    value = p.graph[0] if p.graph else p.default
    key = f"{indent}{p.name}: {yaml_value(value)}"
    meaning = p.meaning
    if p.graph:
        graph = f"graph (node default {yaml_value(p.default)}): {p.graph[1]}"
        meaning = f"{meaning} | {graph}" if meaning else graph
    if not meaning:
        return [key]
    column = max(COMMENT_COLUMN, len(key) + 2)
    if column > WIDTH - 40:  # a long value: its meaning above it
        return [*_wrap(meaning, indent), *_long_list(key, value)]
    first, *rest = textwrap.wrap(meaning, WIDTH - column - 2)
    return [f"{key:<{column}}# {first}", *(" " * column + "# " + r for r in rest)]


_YAML_HEADER = f"""\
# Parameters of the stereo tracking graph (ROS 2 parameter file, one section per node).
# GENERATED by `{COMMAND}` from the nodes' parameter dataclasses
# (tracking_bringup/parameters.py lists them): do not edit, change the dataclass (a default, a
# meaning) or GRAPH_VALUES there (the graph's own values) and run it again; a test fails when
# this file is not what it writes. Used by `stereo_tracking_launch`, `stereo_tracking_demo` and
# launch/stereo_tracking.launch.py: <executable> --ros-args --params-file pipeline.params.yaml
# Every parameter of every node, at the node's default unless its comment says "graph"; the
# reference with allowed values: docs/parameters.md.
"""

_LAUNCH_YAML = """\
# Host profiles of the process launcher (`stereo_tracking_launch --host NAME`; no node reads this
# section; tracking_bringup.parameters.LAUNCH_PROFILES): which nodes each host starts, and how
# the hosts discover each other. The whole graph is the union of the profiles; the player waits
# for the subscriptions of all of it. Give the other host's address with `--peers ADDR`
# (discovery "peers", no multicast needed) or use `--discovery subnet` (multicast). README,
# "Across machines".
stereo_tracking_launch:
  ros__parameters:
    # the player's images on the link, on every host started with --host: raw (exact), png
    # (lossless) or jpeg (jpeg_quality); bandwidth, CPU and figures: docs/bags_and_cameras.md
    image_transport: {image_transport}  # multi-host
    hosts:
"""


def pipeline_yaml() -> str:
    """The text of ``config/pipeline.params.yaml``."""
    out = [_YAML_HEADER, "\n"]
    for node in NODE_PARAMETERS:
        out.append(f"{node}:\n  ros__parameters:\n")
        for cls, params in node_sections(node):
            out += [line + "\n" for line in _wrap(f"{cls.__name__}: {_summary(cls)}", "    ")]
            for p in params:
                out += [line + "\n" for line in _yaml_entry(p, "    ")]
        out.append("\n")
    out.append(_LAUNCH_YAML.format(image_transport=yaml_value(LAUNCH_PROFILES["image_transport"])))
    for host, body in LAUNCH_PROFILES["hosts"].items():
        out.append(f"      {host}:\n")
        out += [f"        {key}: {yaml_value(value)}\n" for key, value in body.items()]
    return "".join(out)


def allowed(p: Parameter) -> str:
    """The allowed values of ``p`` in words (its ``param`` rules)."""
    r = p.rule
    parts = []
    if r.get("choices") is not None:
        parts.append(" \\| ".join(f"`{c}`" for c in r["choices"]))
    low, high = r.get("low"), r.get("high")
    if low is not None and high is not None:
        parts.append(
            f"{'(' if r.get('low_open') else '['}{low}, {high}{')' if r.get('high_open') else ']'}"
        )
    elif low is not None:
        parts.append(f"{'>' if r.get('low_open') else '>='} {low}")
    elif high is not None:
        parts.append(f"{'<' if r.get('high_open') else '<='} {high}")
    if r.get("length") is not None:
        parts.append(f"{r['length']} values")
    if r.get("multiple_of"):
        parts.append(f"multiple of {r['multiple_of']} (or 0)")
    return ", ".join(parts)


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;")


def parameters_markdown() -> str:
    """The text of ``docs/parameters.md``."""
    out = [
        "# Node parameters\n\n",
        f"GENERATED by `{COMMAND}` from the parameter dataclasses that\n",
        "`tracking_bringup/parameters.py` lists (do not edit: change the dataclass and run it\n",
        "again; a test fails when this file is out of date). *default*: the node's own; *graph*:\n",
        "the value in `src/tracking_bringup/config/pipeline.params.yaml` where it differs, with\n",
        "its reason, or how the launchers set it on each run. Every node also takes the process\n",
        "parameters (`ProcessParameters`). Why a default was chosen, on which data: the package\n",
        "docs (docs/detector.md, docs/stereo_depth.md, docs/tracker.md, docs/eval.md).\n",
    ]
    shown = set()  # the process parameters: once, with the first node
    for node in NODE_PARAMETERS:
        out.append(f"\n## {node}\n")
        for cls, params in node_sections(node):
            if cls in shown:  # its rows where this node's differ
                params = [p for p in params if p.graph or p.launcher]
                out.append(f"\n`{cls.__name__}`: as above" + (", but:\n\n" if params else ".\n"))
            else:
                out.append(f"\n`{cls.__module__}.{cls.__name__}`: {_cell(_summary(cls))}\n\n")
            shown.add(cls)
            if params:
                out.append("| parameter | default | graph | allowed | meaning |\n")
                out.append("|---|---|---|---|---|\n")
            for p in params:
                graph = ""
                if p.graph:
                    graph = f"`{yaml_value(p.graph[0])}`: {p.graph[1]}"
                elif p.launcher:
                    graph = f"set by the launchers: {p.launcher}"
                out.append(
                    f"| `{p.name}` | `{_cell(yaml_value(p.default))}` | {_cell(graph)} | "
                    f"{allowed(p)} | {_cell(p.meaning)} |\n"
                )
    return "".join(out)


def generated() -> dict[Path, str]:
    """Each generated file and its text."""
    return {PARAMS_FILE: pipeline_yaml(), DOCS_FILE: parameters_markdown()}


def stale() -> list[Path]:
    """The generated files whose committed text differs from what the generator writes."""
    return [p for p, text in generated().items() if not p.is_file() or p.read_text() != text]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=COMMAND, description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="only check they are up to date")
    args = parser.parse_args(argv)
    if args.check:
        for path in stale():
            print(f"{path}: not up to date; run {COMMAND}", file=sys.stderr)
        return 1 if stale() else 0
    for path, text in generated().items():
        path.write_text(text)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
