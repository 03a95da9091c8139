"""Standard ROS 2 launch file of the stereo tracking graph (for a full ROS 2 install:
``ros2 launch tracking_bringup stereo_tracking.launch.py [params_file:=FILE] [record:=false]``).

It is built from the same node list (``tracking_bringup.graph``) and parameter file as the
project's own process launcher, ``stereo_tracking_launch``.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from tracking_bringup.environment import graph_environment

from tracking_bringup import graph


def generate_launch_description():
    share = get_package_share_directory("tracking_bringup")
    params = LaunchConfiguration("params_file")
    actions = [
        DeclareLaunchArgument(
            "params_file",
            default_value=os.path.join(share, "config", "pipeline.params.yaml"),
            description="ROS parameter file of all nodes",
        ),
        DeclareLaunchArgument("record", default_value="true", description="run bag_recorder"),
    ]
    env = {k: v for k, v in graph_environment({}).items() if k != "PYTHONUNBUFFERED"}
    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = os.path.join(share, "config", "fastdds_profile.xml")
    for spec in graph.PIPELINE:
        actions.append(
            Node(
                package=spec.package,
                executable=spec.executable,
                name=spec.name,
                parameters=[params],
                additional_env=env,
                output="screen",
                condition=IfCondition(LaunchConfiguration("record")) if spec.optional else None,
            )
        )
    return LaunchDescription(actions)
