"""ROS parameters declared from a node's config dataclass, typed and validated at start-up.

Each node describes its parameters ONCE, as a dataclass whose fields are the parameters (name,
default, and with :func:`param` the allowed range or choices). :func:`declare_config` declares
every field on the node with dynamic typing (so a YAML ``16`` or ``-p process_noise:=8`` for a
double is accepted instead of rclpy's InvalidParameterTypeException traceback), converts each value
to its field's type with :func:`coerce` (integers accepted for floats; booleans strict: only
true/false; integers must be whole numbers; floats must be finite unless a field allows
otherwise), checks the field's range and choices, then calls the dataclass's own ``validate()``
for rules between fields. Offline tools build the same dataclass from a parameter file with
:func:`config_from_values`. Any problem is a :class:`ParameterError` naming the parameter; a
node's ``main`` prints it as one line with :func:`parameter_error_line` and exits with code 2.
No rclpy at import time.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
from typing import Any

from .process_priority import NICE_MAX, NICE_MIN

#: exit code of a node or tool started with a bad parameter
EXIT_BAD_PARAMETER = 2
#: the CPUs of a node's process (node_runtime.apply_process_settings)
CPU_AFFINITY_PARAMETER = "cpu_affinity"
#: the niceness of a node's process (node_runtime.apply_process_settings)
NICE_PARAMETER = "nice"
#: whether a node's process keeps freed memory for reuse (node_runtime.apply_process_settings)
KEEP_FREED_MEMORY_PARAMETER = "keep_freed_memory"
#: the rclpy executor that spins a node's process (node_runtime.spin_until_stopped)
EXECUTOR_PARAMETER = "executor"
#: its values: rclpy's EventsExecutor (the default) or its SingleThreadedExecutor
EXECUTORS = ("events", "single_threaded")
#: parameters every node process takes besides its core's config (node_runtime), passed over by
#: :func:`config_from_values` when an offline tool builds a core's config from a node's section
PROCESS_PARAMETERS = (
    CPU_AFFINITY_PARAMETER,
    NICE_PARAMETER,
    KEEP_FREED_MEMORY_PARAMETER,
    EXECUTOR_PARAMETER,
)


class ParameterError(ValueError):
    """A parameter has a wrong type or value; ``name`` is the parameter, the message says what."""

    def __init__(self, name: str, problem: str | None = None):
        if problem is None:  # one "NAME: problem" message
            name, _, problem = name.partition(": ")
        self.name = name
        self.problem = problem
        super().__init__(f"{name}: {problem}" if problem else name)


def param(
    default,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    choices: tuple | None = None,
    multiple_of: int | None = None,
    finite: bool = True,
    length: int | None = None,
):
    """A dataclass field for a parameter: ``default`` plus the allowed values. ``low``/``high``
    bound numbers (and every item of a list), inclusive unless ``*_open``; ``choices`` lists the
    allowed values; ``multiple_of`` (integers; 0 always allowed as "unset"); ``finite``: floats
    must be finite; ``length``: lists must have this many items."""
    rule = {
        "low": low,
        "high": high,
        "low_open": low_open,
        "high_open": high_open,
        "choices": choices,
        "multiple_of": multiple_of,
        "finite": finite,
        "length": length,
    }
    if isinstance(default, list):
        return dataclasses.field(default_factory=lambda: list(default), metadata=rule)
    return dataclasses.field(default=default, metadata=rule)


@dataclasses.dataclass
class ProcessParameters:
    """The process parameters every node takes (:func:`.node_runtime.apply_process_settings`)."""

    # CPUs of the process, a "taskset -c" list ("1", "0-3"); "" = every CPU (ARCHITECTURE.md,
    # "CPU affinity")
    cpu_affinity: str = ""
    # niceness of the process's threads, as "nice -n" (0 = as started; 1..19 lower priority)
    nice: int = param(0, low=NICE_MIN, high=NICE_MAX)
    # freed memory kept in the process for reuse (glibc mallopt): a frame's large buffers cost
    # no fresh pages
    keep_freed_memory: bool = True
    # rclpy executor: "events" (EventsExecutor, its wait in C++: less CPU per message) or
    # "single_threaded"
    executor: str = param(EXECUTORS[0], choices=EXECUTORS)


def _type_name(default) -> str:
    if isinstance(default, bool):
        return "true or false"
    if isinstance(default, int):
        return "an integer"
    if isinstance(default, float):
        return "a number"
    if isinstance(default, str):
        return "a string"
    return "a list"


def coerce(value, default):
    """``value`` converted to the type of ``default`` (bool, int, float, str, list or tuple);
    raises ValueError when it does not fit: booleans only from booleans, integers from integers
    or whole floats, floats from integers or floats, strings from strings or integers (YAML reads
    ``0005`` as 5), lists item by item with the type of the default's items."""
    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
        raise ValueError(value)
    if isinstance(value, bool):
        raise ValueError(value)
    if isinstance(default, int):
        if isinstance(value, float) and value.is_integer():
            return int(value)
        if not isinstance(value, int):
            raise ValueError(value)
        return value
    if isinstance(default, float):
        if not isinstance(value, (int, float)):
            raise ValueError(value)
        return float(value)
    if isinstance(default, (list, tuple)):
        if not isinstance(value, (list, tuple)):
            raise ValueError(value)
        items = [coerce(v, default[0]) if default else v for v in value]
        return tuple(items) if isinstance(default, tuple) else items
    if isinstance(value, int):  # "-p sequence:=0005" arrives as the integer 5
        return str(value)
    if not isinstance(value, str):
        raise ValueError(value)
    return value


def _check_number(v, rule: dict) -> str | None:
    if isinstance(v, float) and rule.get("finite", True) and not math.isfinite(v):
        return "must be finite"
    low, high = rule.get("low"), rule.get("high")
    if low is not None and (v <= low if rule.get("low_open") else v < low):
        return f"must be {'>' if rule.get('low_open') else '>='} {low}"
    if high is not None and (v >= high if rule.get("high_open") else v > high):
        return f"must be {'<' if rule.get('high_open') else '<='} {high}"
    return None


def check_value(name: str, raw, default, rule: dict | None = None):
    """``raw`` converted to the type of ``default`` and checked against ``rule`` (see
    :func:`param`); raises ParameterError naming ``name``."""
    rule = rule or {}
    try:
        value = coerce(raw, default)
    except (TypeError, ValueError):
        what = _type_name(default)
        if isinstance(default, (list, tuple)) and default:
            what = f"a list of {type(default[0]).__name__} values"
        raise ParameterError(name, f"expected {what}, got {raw!r}") from None
    items = value if isinstance(value, (list, tuple)) else [value]
    if rule.get("length") is not None and len(items) != rule["length"]:
        raise ParameterError(name, f"expected {rule['length']} values, got {len(items)}")
    for v in items:
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            problem = _check_number(v, rule)
            if problem:
                raise ParameterError(name, f"{problem}, got {raw!r}")
    choices = rule.get("choices")
    if choices is not None and value not in choices:
        raise ParameterError(name, f"{value!r} is not one of {', '.join(str(c) for c in choices)}")
    m = rule.get("multiple_of")
    if m and isinstance(value, int) and value % m:
        raise ParameterError(name, f"must be a multiple of {m} (or 0), got {value}")
    return value


def defaults_of(cls) -> dict[str, Any]:
    """Parameter name -> default of a config dataclass."""
    out = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            out[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            out[f.name] = f.default_factory()
    return out


def config_from_values(
    cls,
    values: dict,
    source: str | None = None,
    rules: dict[str, dict] | None = None,
    rename: dict[str, str] | None = None,
):
    """An instance of the config dataclass ``cls`` from field name -> raw value (missing names
    keep their defaults), every value typed and range-checked (the fields' ``param`` rules,
    updated by ``rules``), then ``cls.validate()`` if defined (its ValueError, when not already a
    ParameterError, is reported as one). Unknown names are refused. Errors name the parameter
    (``rename``: field -> parameter name), prefixed by ``source`` (e.g. a file name). The
    process's own parameters (``PROCESS_PARAMETERS``) are passed over unless ``cls`` has them."""
    rename = rename or {}
    prefix = f"{source}: " if source else ""

    def label(field_name: str) -> str:
        return prefix + rename.get(field_name, field_name)

    defaults = defaults_of(cls)
    field_rules = {f.name: dict(f.metadata) for f in dataclasses.fields(cls)}
    for name, extra in (rules or {}).items():
        field_rules.setdefault(name, {}).update(extra)
    kwargs = {}
    for name, raw in values.items():
        if name not in defaults and name in PROCESS_PARAMETERS:
            continue
        if name not in defaults:
            raise ParameterError(label(name), "unknown parameter")
        try:
            kwargs[name] = check_value(name, raw, defaults[name], field_rules.get(name))
        except ParameterError as exc:
            raise ParameterError(label(name), exc.problem) from None
    config = cls(**kwargs)
    validate = getattr(config, "validate", None)
    if validate is not None:
        try:
            validate()
        except ParameterError as exc:
            raise ParameterError(label(exc.name), exc.problem) from None
        except ValueError as exc:
            name, sep, problem = str(exc).partition(": ")
            if not sep or not re.fullmatch(r"\w+(, \w+)*", name):
                name, problem = cls.__name__, str(exc)
            raise ParameterError(label(name), problem) from None
    return config


def _ros_default(value):
    """A default as rclpy can declare it (tuples become lists)."""
    return list(value) if isinstance(value, tuple) else value


def declare_config(
    node,
    cls,
    skip: tuple[str, ...] = (),
    rename: dict[str, str] | None = None,
    rules: dict[str, dict] | None = None,
):
    """Declare every field of the config dataclass ``cls`` (except ``skip``; parameter names
    from ``rename``, field -> name) as a dynamically typed parameter of ``node`` and return the
    validated config (raises ParameterError naming the parameter; ``rules`` as in
    :func:`config_from_values`)."""
    from rcl_interfaces.msg import ParameterDescriptor

    rename = rename or {}
    desc = ParameterDescriptor(dynamic_typing=True)
    values = {}
    for name, default in defaults_of(cls).items():
        if name in skip:
            continue
        pname = rename.get(name, name)
        values[name] = node.declare_parameter(pname, _ros_default(default), desc).value
    return config_from_values(cls, values, rules=rules, rename=rename)


def closest(name: str, candidates) -> str:
    """`` (did you mean X?)`` with the closest of ``candidates`` to ``name``, or ``""``."""
    match = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.6)
    return f" (did you mean {match[0]}?)" if match else ""


#: parameters rclpy itself may declare later (QoS overrides of a publisher or subscription)
_LATER_PREFIXES = ("qos_overrides.",)


def check_overrides(node) -> None:
    """Raise ParameterError for a parameter given to ``node`` (in a parameter file section that
    addresses it, or ``-p NAME:=VALUE``) that the node does not declare: ROS would leave it
    unused without a word (``min_hit:=5`` for ``min_hits``). Called once the node declared
    every parameter; the error names the closest declared one."""
    overrides = getattr(node, "_parameter_overrides", None) or {}  # rclpy keeps no public copy
    declared = set(node.list_parameters([], 0).names)
    for name in sorted(overrides):
        if name not in declared and not name.startswith(_LATER_PREFIXES):
            raise ParameterError(name, "unknown parameter of this node" + closest(name, declared))


def parameter_error_line(node_name: str, exc: ParameterError) -> str:
    """The one line a node prints for a bad parameter."""
    return f"error: {node_name}: parameter {exc.name}: {exc.problem}"
