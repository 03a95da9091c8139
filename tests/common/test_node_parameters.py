"""Parameters declared from a config dataclass (dynamically typed, converted and checked)."""

from dataclasses import dataclass

import pytest
from rclpy.parameter import Parameter
from vehicle_common.node_parameters import ParameterError, declare_config, param


@dataclass
class _Example:
    score: float = param(0.3, low=0.0, high=1.0)
    types: list = param(["Car", "Van"])
    n: int = param(2, low=1)
    method: str = param("a", choices=("a", "b"))


def test_declare_config_accepts_an_int_for_a_float_and_names_a_bad_one(rclpy_context):
    import rclpy

    node = rclpy.create_node(
        "param_test",
        context=rclpy_context,
        parameter_overrides=[
            Parameter("score", value=1),
            Parameter("types", value=["Car"]),
            Parameter("how", value="b"),
        ],
    )
    try:
        cfg = declare_config(node, _Example, rename={"method": "how"})
        assert (cfg.score, cfg.types, cfg.n, cfg.method) == (1.0, ["Car"], 2, "b")
        assert isinstance(cfg.score, float)
    finally:
        node.destroy_node()
    for name, value, needle in (
        ("score", "high", "score: expected a number, got 'high'"),
        ("score", 1.5, "score: must be <= 1.0"),
        ("n", 0, "n: must be >= 1"),
        ("how", "c", "how: 'c' is not one of a, b"),
    ):
        bad = rclpy.create_node(
            "param_test_bad",
            context=rclpy_context,
            parameter_overrides=[Parameter(name, value=value)],
        )
        try:
            with pytest.raises(ParameterError, match=needle):
                declare_config(bad, _Example, rename={"method": "how"})
        finally:
            bad.destroy_node()
