"""Dynamically typed ROS parameters coerced to their defaults' types (shared by the nodes)."""

import pytest
from kitti_player_node.node_parameters import coerce, declare_parameters
from rclpy.parameter import Parameter


def test_coerce_converts_or_refuses():
    assert coerce(10, 1.5) == 10.0 and isinstance(coerce(10, 1.5), float)
    assert coerce("0005", "0000") == "0005"
    assert coerce(3.0, 1) == 3 and isinstance(coerce(3.0, 1), int)
    assert coerce("True", False) is True
    assert coerce(("Car",), ["Car", "Van"]) == ["Car"]
    for value, default in ((3.5, 1), ("yes", False), (True, 1.0), ("Car", ["Car"]), ([1], "x")):
        with pytest.raises(ValueError):
            coerce(value, default)


def test_declare_parameters_accepts_an_int_for_a_float_and_names_a_bad_one(rclpy_context):
    import rclpy

    node = rclpy.create_node(
        "param_test",
        context=rclpy_context,
        parameter_overrides=[Parameter("score", value=1), Parameter("types", value=["Car"])],
    )
    try:
        values = declare_parameters(node, {"score": 0.3, "types": ["Car", "Van"], "n": 2})
        assert values == {"score": 1.0, "types": ["Car"], "n": 2}
        assert isinstance(values["score"], float)
    finally:
        node.destroy_node()
    bad = rclpy.create_node(
        "param_test_bad",
        context=rclpy_context,
        parameter_overrides=[Parameter("score", value="high")],
    )
    try:
        with pytest.raises(ValueError, match="score: expected float, got 'high'"):
            declare_parameters(bad, {"score": 0.3})
    finally:
        bad.destroy_node()
