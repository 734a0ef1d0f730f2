"""Start the triplet_normal node the way ROS users start perception nodes:

    ros2 launch triplet_normal_ros triplet_normal.launch.py input:=/camera/depth/points output:=/camera/depth/normals
    ros2 launch triplet_normal_ros triplet_normal.launch.py preset:=lidar input:=/ouster/points
    ros2 launch triplet_normal_ros triplet_normal.launch.py preset:=lidar params_file:=/path/to/my_params.yaml
    ros2 launch triplet_normal_ros triplet_normal.launch.py namespace:=robot1 use_sim_time:=true log_level:=debug

Arguments: ``input`` and ``output`` remap the node's topics (defaults: the node's own names, so relative ones that
follow the namespace); ``namespace`` puts the node and its relative topics under it (default: none); ``preset`` picks
a parameter file installed under ``share/triplet_normal_ros/config/``: ``params`` (the node's defaults, every
parameter listed), ``depth_camera`` or ``lidar`` (docs/NODE.md, "Sensor presets").

Which parameters win: the preset's file is always loaded; ``params_file`` (default: empty, none) is a ROS 2 parameter
file of your own, loaded after it, so each key your file sets overrides the preset's and every other key keeps the
preset's value; ``use_sim_time``, when given (default: not given), comes last and so wins over both files, and when
not given the files' own ``use_sim_time`` (if any) stands. ``log_level`` (default info)
is the node's ``--log-level``. The node also publishes its health on ``/diagnostics`` (docs/NODE.md).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchContext, LaunchDescription

PACKAGE = "triplet_normal_ros"
EXECUTABLE = "node"
NODE_NAME = "triplet_normal"
#: The parameter files under share/<package>/config/ that `preset` may name.
PRESETS = ["params", "depth_camera", "lidar"]


def generate_launch_description() -> LaunchDescription:
    """Seven arguments and one node; the node is made at launch (`_node`), once the arguments' values are known."""
    return LaunchDescription(
        [
            DeclareLaunchArgument("input", default_value="input", description="PointCloud2 topic to read"),
            DeclareLaunchArgument(
                "output", default_value="output", description="topic for the clouds with normals and curvature"
            ),
            DeclareLaunchArgument(
                "namespace", default_value="", description="namespace of the node and of its relative topics"
            ),
            DeclareLaunchArgument(
                "preset",
                default_value="params",
                choices=PRESETS,
                description="installed parameter file, always loaded first: params (the node's defaults), "
                "depth_camera or lidar",
            ),
            DeclareLaunchArgument(
                "params_file",
                default_value="",
                description="your own ROS 2 parameter file, loaded after the preset: each key it sets overrides the "
                "preset's (default: none)",
            ),
            DeclareLaunchArgument(
                "use_sim_time",
                default_value="",
                choices=["", "true", "false"],
                description="true: follow /clock (a bag played with --clock, a simulator); given, it overrides both "
                "files; not given, the files' own use_sim_time (or false) stands",
            ),
            DeclareLaunchArgument(
                "log_level",
                default_value="info",
                description="the node's --log-level: debug, info, warn, error or fatal (or logger:=level)",
            ),
            OpaqueFunction(function=_node),
        ]
    )


def _node(context: LaunchContext) -> list[Node]:
    """The package's ``node`` executable: the preset's file, then the user's when one is given (ROS 2 applies
    parameter files in order, a later file's keys over an earlier one's), then ``use_sim_time`` when it is given. Made
    at launch because whether there is a second file, or a sim-time override, depends on the arguments' values, and an
    empty path would not load."""
    config = os.path.join(get_package_share_directory(PACKAGE), "config")
    files = [os.path.join(config, LaunchConfiguration("preset").perform(context) + ".yaml")]
    own = LaunchConfiguration("params_file").perform(context)
    if own:
        files.append(own)
    sim_time = LaunchConfiguration("use_sim_time").perform(context)
    overrides = [{"use_sim_time": sim_time == "true"}] if sim_time else []
    return [
        Node(
            package=PACKAGE,
            executable=EXECUTABLE,
            name=NODE_NAME,
            namespace=LaunchConfiguration("namespace"),
            parameters=[*files, *overrides],
            remappings=[("input", LaunchConfiguration("input")), ("output", LaunchConfiguration("output"))],
            ros_arguments=["--log-level", LaunchConfiguration("log_level")],
            output="screen",
            emulate_tty=True,
        )
    ]
