"""Standard ROS 2 launch file of the stereo tracking graph (for a full ROS 2 install:
``ros2 launch tracking_bringup stereo_tracking.launch.py [params_file:=FILE]
[params_replace:=true] [record:=false] [namespace:=/rig2]``).

It is built with the same plan (``tracking_bringup.graph.plan``: node list, the detector's
subscriptions following its ``backend``, the player's following its ``lockstep``, the player's
``wait_for_topics``, the latest-frame nodes' ``frame_queue``) and parameter file as the project's
own process launcher, ``stereo_tracking_launch``; a test keeps them in sync. ``ros2 launch``
starts every node at once; the player is told how many subscriptions every edge of the graph
(of the nodes actually launched) must have matched and publishes its first frame only then, so
no node misses frame 0.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from tracking_bringup.environment import graph_environment

from tracking_bringup import graph, parameter_file

PIPELINE = "pipeline.params.yaml"


def _environment(share: str) -> dict:
    env = {k: v for k, v in graph_environment({}).items() if k != "PYTHONUNBUFFERED"}
    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = os.path.join(share, "config", "fastdds_profile.xml")
    return env


def _graph_nodes(context, share: str):
    """The graph's Node actions for the launch arguments' values. The parameter file is read
    and checked once (``tracking_bringup.parameter_file``) and each node gets its section under
    its fully qualified name, so a graph in a namespace runs with the file's values too (a
    ``kitti_player:`` section is otherwise read by ``/kitti_player`` only)."""
    params_file = LaunchConfiguration("params_file").perform(context)
    replace = LaunchConfiguration("params_replace").perform(context).lower() in ("true", "1")
    # on top of the pipeline file key by key, unless params_replace:=true (as the launcher)
    files = parameter_file.layers(params_file, replace, os.path.join(share, "config", PIPELINE))
    namespace = parameter_file.check_namespace(LaunchConfiguration("namespace").perform(context))
    record = LaunchConfiguration("record").perform(context).lower() in ("true", "1")
    env = _environment(share)
    nodes = [n for n in graph.PIPELINE if record or not n.optional]
    params = parameter_file.node_parameters(files, [n.name for n in graph.PIPELINE], namespace)
    resolved = str(
        parameter_file.write_node_parameters(
            {n.name: params[n.name] for n in nodes},
            namespace,
            parameter_file.temporary_path("parameters_"),
            source=files,
        )
    )
    actions = []
    for spec, extra in graph.plan(nodes, params):
        actions.append(
            Node(
                package=spec.package,
                executable=spec.executable,
                name=spec.name,
                namespace=namespace,
                parameters=[resolved, extra] if extra else [resolved],
                additional_env=env,
                output="screen",
            )
        )
    return actions


def generate_launch_description():
    share = get_package_share_directory("tracking_bringup")
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "params_file",
                default_value=os.path.join(share, "config", PIPELINE),
                description="ROS parameter file, read on top of the pipeline file key by key",
            ),
            DeclareLaunchArgument(
                "params_replace",
                default_value="false",
                description="true: params_file instead of the pipeline file",
            ),
            DeclareLaunchArgument("record", default_value="true", description="run bag_recorder"),
            DeclareLaunchArgument(
                "namespace", default_value="", description="ROS namespace of the whole graph"
            ),
            OpaqueFunction(function=_graph_nodes, args=[share]),
        ]
    )
