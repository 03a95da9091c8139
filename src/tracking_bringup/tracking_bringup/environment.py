"""The DDS environment every process of the graph runs with."""

from __future__ import annotations

import os
from pathlib import Path

CONFIG_DIR = Path(__file__).resolve().parent.parent / "config"
FASTDDS_PROFILE = CONFIG_DIR / "fastdds_profile.xml"
PARAMS_FILE = CONFIG_DIR / "pipeline.params.yaml"


def graph_environment(base: dict[str, str] | None = None) -> dict[str, str]:
    """``base`` (default: os.environ) plus the graph's DDS settings, unless already set:
    discovery on this host only (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) and the Fast DDS
    profile with a shared-memory segment large enough for full KITTI images."""
    env = dict(os.environ if base is None else base)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    env.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(FASTDDS_PROFILE))
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def apply_graph_environment() -> None:
    """Set the graph's DDS settings in this process (before rclpy.init)."""
    os.environ.update(graph_environment())
