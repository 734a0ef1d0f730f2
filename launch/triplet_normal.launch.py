"""Start the triplet_normal node the way ROS users start perception nodes:

    ros2 launch triplet_normal_ros triplet_normal.launch.py input:=/camera/depth/points output:=/camera/depth/normals
    ros2 launch triplet_normal_ros triplet_normal.launch.py params_file:=/path/to/my_params.yaml

Arguments: ``input`` and ``output`` remap the node's topics (defaults: the node's own names), ``params_file`` is a
ROS 2 parameter file (default: the installed ``share/triplet_normal_ros/config/params.yaml``). The node also
publishes its health on ``/diagnostics`` (docs/NODE.md).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = "triplet_normal_ros"
EXECUTABLE = "node"
NODE_NAME = "triplet_normal"


def generate_launch_description() -> LaunchDescription:
    """Three arguments and one node: the package's ``node`` executable with the parameter file and the remaps."""
    default_params = os.path.join(get_package_share_directory(PACKAGE), "config", "params.yaml")
    return LaunchDescription(
        [
            DeclareLaunchArgument("input", default_value="input", description="PointCloud2 topic to read"),
            DeclareLaunchArgument(
                "output", default_value="output", description="topic for the clouds with normals and curvature"
            ),
            DeclareLaunchArgument(
                "params_file", default_value=default_params, description="ROS 2 parameter file for the node"
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
