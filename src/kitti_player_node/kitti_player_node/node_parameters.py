"""ROS parameters declared with dynamic typing and converted to their defaults' types.

A parameter file or ``-p`` override may give ``rate:=10`` for a float or ``sequence:=0005`` for
a string; declaring with ``dynamic_typing`` accepts any type, and :func:`coerce` converts it to
the type of the default or raises ValueError, so that a node reports one clear line instead of
rclpy's InvalidParameterTypeException traceback. Used by the nodes of the graph.
"""

from __future__ import annotations


def coerce(value, default):
    """``value`` converted to the type of ``default`` (bool, int, float, str or list);
    raises ValueError when it does not fit."""
    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "false"):
            return value.lower() == "true"
        raise ValueError(value)
    if isinstance(default, int):
        if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
            raise ValueError(value)
        return int(value)
    if isinstance(default, float):
        if isinstance(value, bool):
            raise ValueError(value)
        return float(value)
    if isinstance(default, (list, tuple)):
        if not isinstance(value, (list, tuple)):
            raise ValueError(value)
        return list(value)
    if isinstance(value, (list, bytes)):
        raise ValueError(value)
    return str(value)


def declare_parameters(node, defaults: dict) -> dict:
    """Declare every parameter of ``defaults`` on ``node`` (dynamically typed) and return their
    values coerced to the defaults' types. Raises ValueError("NAME: expected T, got V")."""
    from rcl_interfaces.msg import ParameterDescriptor

    desc = ParameterDescriptor(dynamic_typing=True)
    values = {}
    for name, default in defaults.items():
        raw = node.declare_parameter(name, default, desc).value
        try:
            values[name] = coerce(raw, default)
        except (TypeError, ValueError):
            raise ValueError(f"{name}: expected {type(default).__name__}, got {raw!r}") from None
    return values
