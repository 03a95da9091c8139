"""Standard ROS 2 launch file of the stereo tracking graph (for a full ROS 2 install:
``ros2 launch tracking_bringup stereo_tracking.launch.py [params_file:=FILE] [record:=false]``).

It is built from the same node list (``tracking_bringup.graph``) and parameter file as the
project's own process launcher, ``stereo_tracking_launch``. ``ros2 launch`` starts every node at
once; the player is told how many subscriptions every edge of the graph must have matched
(``wait_for_topics``, from the graph of the nodes actually launched and the detector's backend)
and publishes its first frame only then, so no node misses frame 0.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from tracking_bringup.environment import graph_environment

from tracking_bringup import graph


def _graph_nodes(context):
    params = LaunchConfiguration("params_file").perform(context)
    record = LaunchConfiguration("record").perform(context).strip().lower() in ("true", "1")
    nodes = [n for n in graph.PIPELINE if record or not n.optional]
    backend = graph.parameter_value(params, graph.DETECTOR.name, "backend", "cnn")
    nodes = graph.with_detector_backend(nodes, str(backend))
    lockstep = graph.parameter_value(params, graph.PLAYER.name, "lockstep", False)
    nodes = graph.with_lockstep(nodes, graph.as_bool(lockstep))
    extra = graph.source_parameters(nodes)  # every edge of the graph, for the player
    if graph.as_bool(lockstep):  # K frames in flight may wait at a latest-frame node
        window = graph.parameter_value(params, graph.PLAYER.name, "lockstep_window", 1)
        extra.update(graph.frame_queue_parameters(nodes, int(window)))
    share = get_package_share_directory("tracking_bringup")
    env = {k: v for k, v in graph_environment({}).items() if k != "PYTHONUNBUFFERED"}
    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = os.path.join(share, "config", "fastdds_profile.xml")
    return [
        Node(
            package=spec.package,
            executable=spec.executable,
            name=spec.name,
            parameters=[params, extra[spec.name]] if spec.name in extra else [params],
            additional_env=env,
            output="screen",
        )
        for spec in nodes
    ]


def generate_launch_description():
    share = get_package_share_directory("tracking_bringup")
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "params_file",
                default_value=os.path.join(share, "config", "pipeline.params.yaml"),
                description="ROS parameter file of all nodes",
            ),
            DeclareLaunchArgument("record", default_value="true", description="run bag_recorder"),
            OpaqueFunction(function=_graph_nodes),
        ]
    )
