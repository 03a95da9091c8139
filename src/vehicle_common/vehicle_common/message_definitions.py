"""ROS 2 message definitions for rosbags, and ROS 1 -> CDR conversion of recorded messages.

:class:`MessageDefinitions` is a rosbags typestore of the ROS 2 Jazzy types plus, on demand, a
package's ``.msg`` files found under ``share/<pkg>/msg`` (the project's ``stereo_vehicle_msgs``).
The bag recorder takes definitions and RIHS01 hashes from it; the bag player converts messages
of ROS 1 bags (``kitti2bag``) to the CDR a ROS 2 subscriber expects with
:func:`ros1_to_cdr_converter`.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path


class UnknownMessageType(ValueError):
    """No ROS 2 definition of a message type is known (rosbags' Jazzy store, share/<pkg>/msg)."""


def _share_dirs() -> list[Path]:
    """Install prefixes' share folders (AMENT_PREFIX_PATH, then the interpreter's prefix)."""
    dirs = []
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            dirs.append(Path(prefix) / "share")
    dirs.append(Path(sys.prefix) / "share")
    return [d for d in dirs if d.is_dir()]


class MessageDefinitions:
    """Message definitions (msgdef text) and RIHS01 hashes of ROS 2 types.

    Starts from rosbags' Jazzy typestore and registers, on demand, a package's ``.msg`` files
    found under ``share/<pkg>/msg`` (for the project's ``stereo_vehicle_msgs``). ``error``: the
    exception class raised for an unknown type.
    """

    def __init__(self, error: type[Exception] = UnknownMessageType) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        self.error = error
        self._loaded_pkgs: set[str] = set()

    def _load_package(self, pkg: str) -> None:
        from rosbags.typesys import get_types_from_msg

        if pkg in self._loaded_pkgs:
            return
        self._loaded_pkgs.add(pkg)
        for share in _share_dirs():
            msg_dir = share / pkg / "msg"
            if not msg_dir.is_dir():
                continue
            types = {}
            for f in sorted(msg_dir.glob("*.msg")):
                types.update(get_types_from_msg(f.read_text(), f"{pkg}/msg/{f.stem}"))
            self.typestore.register(types)
            return

    def get(self, msgtype: str) -> tuple[str, str]:
        """(msgdef, rihs01) of ``msgtype`` (``pkg/msg/Type``); raises ``error`` if unknown."""
        if msgtype not in self.typestore.types:
            self._load_package(msgtype.split("/")[0])
        if msgtype not in self.typestore.types:
            raise self.error(f"{msgtype}: unknown message type (no .msg definition found)")
        # Dependencies of a custom type may live in another package.
        try:
            msgdef, _ = self.typestore.generate_msgdef(msgtype, ros_version=2)
        except KeyError as exc:
            self._load_package(str(exc.args[0]).split("/")[0])
            msgdef, _ = self.typestore.generate_msgdef(msgtype, ros_version=2)
        return msgdef, self.typestore.hash_rihs01(msgtype)


#: ROS 1 type names that ROS 2 spells differently (rosbags' own list)
ROS1_RENAMES = {"tf/msg/tfMessage": "tf2_msgs/msg/TFMessage"}


def ros2_type_name(ros1_type: str) -> str:
    """The ROS 2 name of a ROS 1 message type as rosbags reads it (``pkg/msg/Type``)."""
    return ROS1_RENAMES.get(ros1_type, ros1_type)


def ros1_to_cdr_converter(
    ros1_typestore, ros1_type: str, definitions: MessageDefinitions
) -> Callable[[bytes], bytes]:
    """A function turning one serialized ROS 1 message of ``ros1_type`` (as stored in a ROS 1
    bag, whose own definitions are in ``ros1_typestore``) into the little-endian CDR of its ROS 2
    type: byte-level conversion when the layouts agree (Header's ``seq`` dropped), else
    deserialised and migrated field by field (e.g. CameraInfo's ``D``/``K``/``R``/``P`` ->
    ``d``/``k``/``r``/``p``). Raises ``definitions.error`` when the ROS 2 type is unknown."""
    from rosbags.convert.converter import is_same_wireformat, migrate_message

    dst_type = ros2_type_name(ros1_type)
    definitions.get(dst_type)  # loads the package; raises for an unknown type
    dst = definitions.typestore
    try:
        same = is_same_wireformat(ros1_typestore, dst, ros1_type, dst_type)
    except KeyError as exc:  # a nested type without a ROS 2 definition
        raise definitions.error(f"{ros1_type}: no ROS 2 definition of {exc.args[0]}") from None
    if same:
        return lambda raw: bytes(dst.ros1_to_cdr(raw, dst_type))
    cache: dict[str, object] = {}

    def migrate(raw: bytes) -> bytes:
        msg = ros1_typestore.deserialize_ros1(raw, ros1_type)
        out = migrate_message(ros1_typestore, dst, ros1_type, dst_type, cache, msg)
        return bytes(dst.serialize_cdr(out, dst_type, little_endian=True))

    return migrate
