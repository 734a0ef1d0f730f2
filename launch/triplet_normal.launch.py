"""Start the triplet_normal node the way ROS users start perception nodes:

    ros2 launch triplet_normal_ros triplet_normal.launch.py input:=/camera/depth/points output:=/camera/depth/normals
    ros2 launch triplet_normal_ros triplet_normal.launch.py preset:=lidar input:=/ouster/points
    ros2 launch triplet_normal_ros triplet_normal.launch.py params_file:=/path/to/my_params.yaml

Arguments: ``input`` and ``output`` remap the node's topics (defaults: the node's own names); ``preset`` picks a
parameter file installed under ``share/triplet_normal_ros/config/``: ``params`` (the node's defaults, every parameter
listed), ``depth_camera`` or ``lidar`` (README, "Sensor presets"); ``params_file`` is any ROS 2 parameter file
(default: the preset's). The node also publishes its health on ``/diagnostics`` (docs/NODE.md).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription

PACKAGE = "triplet_normal_ros"
EXECUTABLE = "node"
NODE_NAME = "triplet_normal"
#: The parameter files under share/<package>/config/ that `preset` may name.
PRESETS = ["params", "depth_camera", "lidar"]


def generate_launch_description() -> LaunchDescription:
    """Four arguments and one node: the package's ``node`` executable with the parameter file and the remaps."""
    config = os.path.join(get_package_share_directory(PACKAGE), "config")
    # A list of text and substitutions is joined at launch: <share>/config/<preset>.yaml (on every distribution).
    default_params = [config + os.sep, LaunchConfiguration("preset"), ".yaml"]
    return LaunchDescription(
        [
            DeclareLaunchArgument("input", default_value="input", description="PointCloud2 topic to read"),
            DeclareLaunchArgument(
                "output", default_value="output", description="topic for the clouds with normals and curvature"
            ),
            DeclareLaunchArgument(
                "preset",
                default_value="params",
                choices=PRESETS,
                description="installed parameter file: params (the node's defaults), depth_camera or lidar",
            ),
            DeclareLaunchArgument(
                "params_file", default_value=default_params, description="ROS 2 parameter file (default: the preset)"
            ),
            Node(
                package=PACKAGE,
                executable=EXECUTABLE,
                name=NODE_NAME,
                parameters=[LaunchConfiguration("params_file")],
                remappings=[("input", LaunchConfiguration("input")), ("output", LaunchConfiguration("output"))],
                output="screen",
                emulate_tty=True,
            ),
        ]
    )
