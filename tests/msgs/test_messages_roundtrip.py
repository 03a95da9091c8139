"""Every message of the interface package survives CDR serialisation unchanged."""

import inspect

import pytest

rclpy_serialization = pytest.importorskip("rclpy.serialization")
msgs = pytest.importorskip("stereo_vehicle_msgs.msg")

MESSAGE_TYPES = [
    cls for _, cls in inspect.getmembers(msgs, inspect.isclass) if hasattr(cls, "_TYPE_SUPPORT")
]


def _value(type_name: str, seed: int):
    """A non-default value for a rosidl field type."""
    base = type_name.split("[")[0].split("<")[0]
    if base == "boolean":
        return True
    if base in ("float", "double"):
        return 0.5 + seed
    if base.startswith(("int", "uint")) or base in ("octet", "char"):
        return (seed % 3) + 1
    if base == "string":
        return f"value {seed}"
    return None


def _fill(msg, seed: int = 1):
    for name, type_name in msg.get_fields_and_field_types().items():
        seed += 1
        if "/" in type_name:  # nested message(s)
            cls = type(getattr(msg, name))
            if type_name.startswith("sequence<"):
                mod, cname = type_name[len("sequence<") : -1].split("/")
                import importlib

                sub = getattr(importlib.import_module(mod.replace("/", ".") + ".msg"), cname)
                setattr(msg, name, [_fill(sub(), seed), _fill(sub(), seed + 7)])
            else:
                _fill(getattr(msg, name), seed)
                del cls
            continue
        if type_name.startswith("sequence<"):
            setattr(msg, name, [_value(type_name[9:-1], seed), _value(type_name[9:-1], seed + 1)])
        elif "[" in type_name:
            n = int(type_name.split("[")[1].rstrip("]"))
            setattr(msg, name, [_value(type_name, seed + i) for i in range(n)])
        else:
            setattr(msg, name, _value(type_name, seed))
    return msg


def test_all_message_types_found():
    names = {cls.__name__ for cls in MESSAGE_TYPES}
    assert {
        "BoundingBox2D",
        "VehicleDetection2D",
        "VehicleDetection2DArray",
        "VehicleDetection3D",
        "VehicleDetection3DArray",
        "TrackedVehicle",
        "TrackedVehicleArray",
        "KittiObject",
        "KittiFrameLabels",
    } <= names


@pytest.mark.parametrize("cls", MESSAGE_TYPES, ids=lambda c: c.__name__)
def test_roundtrip(cls):
    msg = _fill(cls())
    assert msg != cls()  # the filler changed something
    data = rclpy_serialization.serialize_message(msg)
    back = rclpy_serialization.deserialize_message(data, cls)
    assert back == msg


def test_tracked_vehicle_states_documented_constants():
    tv = msgs.TrackedVehicle
    assert (tv.STATE_TENTATIVE, tv.STATE_CONFIRMED, tv.STATE_COASTING) == (0, 1, 2)


def test_camera_motion_travels_in_the_3d_array():
    import cv2
    import numpy as np
    from stereo_vehicle_msgs.msg import VehicleDetection3DArray
    from tracker_node.conversions import camera_motion_from_msg
    from vehicle_common.frame_messages import read_transform, write_transform

    msg = VehicleDetection3DArray()
    assert camera_motion_from_msg(msg) == (None, [])  # unknown by default
    for rv in ([0.0, 0.0, 0.0], [0.1, -0.2, 0.3], [3.0, 0.1, 0.0], [0.0, 3.1, 0.05], [0, 0, 3.1]):
        R = cv2.Rodrigues(np.array(rv))[0]
        write_transform(R, [0.1, 0.0, -1.8], msg.camera_motion)
        R2, t = read_transform(msg.camera_motion)
        assert np.abs(R2 - R).max() < 1e-12 and msg.camera_motion.rotation.w >= 0
        np.testing.assert_allclose(t, [0.1, 0.0, -1.8])
    msg.camera_motion_dt = 0.1
    motion, problems = camera_motion_from_msg(msg)
    assert not problems and motion.dt == 0.1 and np.allclose(motion.rotation, R)
    msg.camera_motion.rotation.w = msg.camera_motion.rotation.z = 0.0
    msg.camera_motion.rotation.x = msg.camera_motion.rotation.y = 0.0
    motion, problems = camera_motion_from_msg(msg)
    assert motion is None and "camera_motion" in problems[0]
    msg.camera_motion_dt = -0.1
    assert "camera_motion_dt" in camera_motion_from_msg(msg)[1][0]
