"""Start the MRAD detector node (and optionally RViz) against the arm camera.

ros2 launch allo_mrad_ros detect.launch.py [pose_source:=topic] [use_sim_time:=true]
    [config:=/path/mrad.yaml] [mesh:=/path/station.glb] [namespace:=robot1]
    [image_topic:=/cam/image_raw] [camera_info_topic:=...] [pose_topic:=...]
    [sun_topic:=...] [rviz:=true]
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

from allo_mrad_ros import interface

PACKAGE = "allo_mrad_ros"

# (argument, default, description); topic defaults are the allo-bag writer's topics.
ARGUMENTS = [
    (
        "config",
        PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "mrad.yaml"]),
        "parameter file of the node",
    ),
    ("mesh", "", "station CAD model; empty: the config's value (package station.glb)"),
    ("namespace", "", "namespace of the node"),
    ("pose_source", "tf", "camera pose from tf (tf2_ros) or topic (PoseStamped)"),
    ("use_sim_time", "false", "use /clock (true when replaying a bag with --clock)"),
    ("image_topic", interface.IMAGE_TOPIC, "camera image (sensor_msgs/Image)"),
    ("camera_info_topic", interface.CAMERA_INFO_TOPIC, "camera intrinsics"),
    ("pose_topic", interface.POSE_TOPIC, "camera pose when pose_source is topic"),
    ("sun_topic", interface.SUN_DIRECTION_TOPIC, "sun direction (geometry_msgs/Vector3Stamped)"),
    ("rviz", "false", "also start RViz with the package's view"),
]


def generate_launch_description() -> LaunchDescription:
    """The node with its parameter file, overrides and topic remappings."""
    arguments = [
        DeclareLaunchArgument(name, default_value=default, description=description)
        for name, default, description in ARGUMENTS
    ]
    config = LaunchConfiguration("config")
    overrides = {
        "pose_source": LaunchConfiguration("pose_source"),
        "use_sim_time": ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool),
    }
    detector = Node(
        package=PACKAGE,
        executable="mrad_detector",
        name=interface.NODE_NAME,
        namespace=LaunchConfiguration("namespace"),
        output="screen",
        parameters=[config, overrides, {"mesh": LaunchConfiguration("mesh")}],
        remappings=[
            (interface.IMAGE_TOPIC, LaunchConfiguration("image_topic")),
            (interface.CAMERA_INFO_TOPIC, LaunchConfiguration("camera_info_topic")),
            (interface.POSE_TOPIC, LaunchConfiguration("pose_topic")),
            (interface.SUN_DIRECTION_TOPIC, LaunchConfiguration("sun_topic")),
        ],
    )
    rviz = Node(
        package="rviz2",
        executable="rviz2",
        name="rviz2",
        arguments=["-d", PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "mrad.rviz"])],
        parameters=[
            {"use_sim_time": ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool)}
        ],
        condition=IfCondition(LaunchConfiguration("rviz")),
    )
    return LaunchDescription([*arguments, detector, rviz])
