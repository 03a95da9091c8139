"""The graph's ROS parameter file, read once by the launchers and handed to each node as the
parameters of its fully qualified name.

A ROS parameter file addresses nodes by name: ``kitti_player:`` is read by rcl as the node
``/kitti_player`` and by no node of a graph moved into ``/rig2`` (which then ran on node
defaults: issue #35). Both launchers therefore read the file here and write, per run, a file
whose sections are the graph's fully qualified node names (``/rig2/kitti_player``): every node
gets exactly the file's values whatever the namespace.

Sections the file may have (a later section that sets the same parameter wins, as in rcl):

- ``NAME`` or ``/NAME``: the node NAME of the graph, in whatever namespace the graph runs;
- ``/**/NAME``: NAME in any namespace; ``/**``: every node;
- ``/NS/NAME`` (rcl's ``*`` and ``**`` wildcards allowed): NAME where the graph runs in
  ``/NS``; sections of other namespaces are left out (another graph's);
- ``stereo_tracking_launch``: the launcher's own (host profiles, ``hosts.py``).

Files layer (issue #42): a user's ``--params`` file is read on top of the pipeline file
(``config/pipeline.params.yaml``), key by key as ``-p`` does (:func:`layers`): each node gets
the pipeline file's parameters with those the user's file sets replaced. ``--params-replace``
uses the user's file alone (every parameter it does not set is the node's default). A file with
only ``vehicle_tracker: min_hits: 4`` used to replace the whole pipeline file silently: the
player lost lockstep and every other node its settings. The run's ``parameters.yaml`` is the
merged result.

A section whose node name is no node of the graph is refused with one line naming it and the
closest valid name (``vehicle_trackr`` -> ``vehicle_tracker``), as is a file that is not valid
YAML (with its line), not a mapping, a section without a ``ros__parameters`` mapping, or a key
given twice in one mapping (YAML keeps the last one silently; named with both lines). Each
node refuses a parameter it does not declare itself (``vehicle_common.node_parameters.
check_overrides``). No rclpy here.
"""

from __future__ import annotations

import atexit
import os
import re
import shutil
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from vehicle_common.node_parameters import closest

from vehicle_common import topics

#: the launcher's own section of the file (host profiles); no node reads it
LAUNCH_SECTION = "stereo_tracking_launch"
_PARAMS_KEY = "ros__parameters"
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


class ParameterFileError(ValueError):
    """The parameter file cannot be used; the message is one line naming the file and where."""


#: one parameter file, or the files of a run in the order they apply (:func:`layers`)
Files = str | os.PathLike | Sequence[str | os.PathLike]


def layers(
    params: str | os.PathLike | None, replace: bool = False, base: str | os.PathLike | None = None
) -> list[Path]:
    """The parameter files of a run, in the order they apply: the pipeline file ``base``
    (default ``config/pipeline.params.yaml``), then ``params`` on top of it key by key;
    ``replace``: ``params`` alone. ValueError (one line) for ``replace`` without ``params``."""
    if base is None:
        from tracking_bringup.environment import PARAMS_FILE as base
    base = Path(base)
    if params is None:
        if replace:
            raise ValueError("--params-replace: give the file with --params FILE")
        return [base]
    params = Path(params)
    if replace or (params.is_file() and base.is_file() and params.samefile(base)):
        return [params]
    return [base, params]


def as_files(files: Files) -> list[Path]:
    """``files`` as a list of paths (one path: a list of one)."""
    if isinstance(files, (str, os.PathLike)):
        return [Path(files)]
    return [Path(f) for f in files]


def describe(files: Files) -> str:
    """``a.yaml`` or ``a.yaml + b.yaml`` (the files in the order they apply)."""
    return " + ".join(str(f) for f in as_files(files))


def missing_file(files: Files) -> str | None:
    """One line naming the first of ``files`` that is no file, else None."""
    for path in as_files(files):
        if not path.is_file():
            return f"{path}: parameter file not found"
    return None


def check_namespace(namespace: str | None) -> str:
    """``namespace`` normalised (``"rig2"`` -> ``"/rig2"``, ``""`` for none); ValueError with
    one line when it is no valid ROS namespace (tokens of letters, digits and ``_``, not
    starting with a digit, no ``__``), e.g. ``rig-2``."""
    ns = topics.normalise_namespace(namespace)
    for token in ns.split("/")[1:]:
        if not _TOKEN.fullmatch(token) or "__" in token:
            raise ValueError(
                f"namespace {namespace!r}: {token!r} is not a valid ROS name (letters, digits "
                "and '_', not starting with a digit, no '__'), e.g. /rig2 or /rig_2"
            )
    return ns


def read_file(path: str | Path) -> dict:
    """The file's top-level mapping; ParameterFileError (one line) when it cannot be read, is
    not valid YAML (its line and problem) or is not a mapping."""
    import yaml

    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise ParameterFileError(f"{path}: parameter file not found") from None
    except OSError as exc:
        raise ParameterFileError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise ParameterFileError(
            f"{path}: not a text file (byte {exc.start} is not UTF-8)"
        ) from None
    try:
        data = yaml.load(text, Loader=_unique_key_loader())  # noqa: S506 (a SafeLoader)
    except _DuplicateKey as exc:
        raise ParameterFileError(f"{path}: {exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ParameterFileError(f"{path}: {where}not valid YAML ({problem})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ParameterFileError(
            f"{path}: expected a mapping of node names to 'ros__parameters', got "
            f"{type(data).__name__}"
        )
    return data


class _DuplicateKey(ValueError):
    pass


def _unique_key_loader():
    """A SafeLoader that refuses a key given twice in one mapping (YAML itself keeps the last:
    a second ``min_hits:`` in a section silently won)."""
    import yaml

    class Loader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            seen: dict = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                line = key_node.start_mark.line + 1
                try:
                    first = seen.get(key)
                    seen.setdefault(key, line)
                except TypeError:  # an unhashable key: the constructor names it
                    continue
                if first is not None:
                    raise _DuplicateKey(
                        f"line {line}: key {key!r} given twice in one mapping (first on line "
                        f"{first}; YAML would keep the last silently)"
                    )
            return super().construct_mapping(node, deep=deep)

    return Loader


def _key_pattern(key: str, namespace: str) -> re.Pattern | None:
    """The fully qualified node names a section key addresses, as a regex (rcl's wildcards:
    ``*`` one token, ``/**`` any number of tokens); a key without a namespace addresses the
    node in the graph's ``namespace``."""
    tokens = key.strip("/").split("/")
    if len(tokens) == 1 and "*" not in tokens[0]:  # NAME or /NAME: this graph's node
        return re.compile(re.escape(f"{namespace}/{tokens[0]}"))
    parts = []
    for token in tokens:
        if token == "**":
            parts.append(r"(/[^/]+)*")
        else:
            parts.append("/" + re.escape(token).replace(r"\*", "[^/]*"))
    return re.compile("".join(parts))


def node_parameters(
    path: Files, node_names: Iterable[str], namespace: str | None = ""
) -> dict[str, dict]:
    """``{node name: {parameter: value}}`` for each of ``node_names`` (the graph's nodes) as
    the file gives them in ``namespace`` (see the module docstring; nodes the file does not
    address get ``{}``). ParameterFileError (one line) for an unknown section, a section without
    a ``ros__parameters`` mapping, or a file that cannot be read. Several files (:func:`layers`):
    each node's parameters of the first, updated key by key by each later one."""
    names = list(node_names)
    if not isinstance(path, (str, os.PathLike)):
        out: dict[str, dict] = {n: {} for n in names}
        for layer in as_files(path):
            for name, values in node_parameters(layer, names, namespace).items():
                out[name].update(values)
        return out
    ns = check_namespace(namespace)
    data = read_file(path)
    out: dict[str, dict] = {n: {} for n in names}
    valid = [*names, LAUNCH_SECTION]
    for key, body in data.items():
        if not isinstance(key, str) or not key.strip("/"):
            raise ParameterFileError(f"{path}: section {key!r}: expected a node name")
        node = key.rstrip("/").rsplit("/", 1)[-1]
        if node == LAUNCH_SECTION:
            continue
        if "*" not in node and node not in names:
            raise ParameterFileError(
                f"{path}: section {key!r}: no node {node!r} in the graph{closest(node, valid)}; "
                f"nodes: {', '.join(names)}"
            )
        if not isinstance(body, dict) or not isinstance(body.get(_PARAMS_KEY), dict):
            raise ParameterFileError(
                f"{path}: section {key!r}: expected a 'ros__parameters:' mapping"
            )
        extra = sorted(set(body) - {_PARAMS_KEY})
        if extra:
            raise ParameterFileError(
                f"{path}: section {key!r}: unexpected {extra[0]!r} beside 'ros__parameters'"
                f"{closest(str(extra[0]), [_PARAMS_KEY])}"
            )
        pattern = _key_pattern(key.rstrip("/"), ns)
        for name in names:
            if pattern.fullmatch(f"{ns}/{name}"):
                out[name].update(body[_PARAMS_KEY])
    return out


def fully_qualified(name: str, namespace: str | None = "") -> str:
    """``/rig2/kitti_player`` (``/kitti_player`` without a namespace)."""
    return f"{topics.normalise_namespace(namespace)}/{name}"


def write_node_parameters(
    params: Mapping[str, Mapping],
    namespace: str | None,
    path: str | Path,
    source: Files | None = None,
) -> Path:
    """Write ``{node: {parameter: value}}`` as a ROS parameter file whose sections are the
    nodes' fully qualified names in ``namespace`` (nodes without parameters are left out)."""
    import yaml

    body = {
        fully_qualified(node, namespace): {_PARAMS_KEY: dict(values)}
        for node, values in params.items()
        if values
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ns = topics.normalise_namespace(namespace) or "/"
    origin = ""
    if source:
        files = as_files(source)
        origin = f" from {files[0]}"
        if len(files) > 1:
            later = ", then ".join(str(f) for f in files[1:])
            origin += f"\n# overridden key by key by {later}"
    head = f"# The graph's parameters{origin}, for the namespace {ns}:\n"
    head += "# each section is a node's fully qualified name (written by the graph's launcher).\n"
    path.write_text(head + yaml.dump(body, Dumper=_dumper(), sort_keys=False))
    return path


def _flow_list(dumper, value):
    return dumper.represent_sequence("tag:yaml.org,2002:seq", value, flow_style=True)


def _dumper():
    import yaml

    class Dumper(yaml.SafeDumper):
        """Block mappings, lists on one line (``match_rows: [94, 375]``)."""

    Dumper.add_representer(list, _flow_list)
    return Dumper


_TEMP_DIR: list[Path] = []


def temporary_path(stem: str) -> Path:
    """A path in a folder of this process's that is removed when it exits (for a launch whose
    caller keeps no log folder)."""
    if not _TEMP_DIR:
        folder = Path(tempfile.mkdtemp(prefix="stereo_tracking_params_"))
        atexit.register(shutil.rmtree, folder, True)
        _TEMP_DIR.append(folder)
    fd, name = tempfile.mkstemp(prefix=stem, suffix=".yaml", dir=_TEMP_DIR[0])
    os.close(fd)
    return Path(name)
