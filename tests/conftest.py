"""Shared test fixtures: the real KITTI samples, an isolated ROS 2 domain, the DDS profile."""

from __future__ import annotations

import os
import random
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED_KITTI = Path(os.environ.get("SHARED_KITTI", REPO.parent / "shared" / "kitti"))

# Every test process gets its own DDS domain, so that test runs (and a demo) on the same
# machine never see each other's topics. Set before rclpy is imported anywhere.
os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 100)))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault(
    "FASTRTPS_DEFAULT_PROFILES_FILE",
    str(REPO / "src" / "tracking_bringup" / "config" / "fastdds_profile.xml"),
)


@pytest.fixture(scope="session")
def shared_kitti() -> Path:
    """Root of ../shared/kitti; skips the test with a clear message when it is absent."""
    if not (SHARED_KITTI / "README.md").is_file():
        pytest.skip(f"real KITTI samples not found at {SHARED_KITTI} (../shared/kitti)")
    return SHARED_KITTI


@pytest.fixture(scope="session")
def kitti_tracking_root(shared_kitti: Path) -> Path:
    return shared_kitti / "tracking" / "training"


@pytest.fixture
def rclpy_context():
    """An initialised rclpy context for in-process node tests, shut down afterwards."""
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx)
    try:
        yield ctx
    finally:
        ctx.try_shutdown()
