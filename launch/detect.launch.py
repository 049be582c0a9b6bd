"""Start the MRAD detector node (and optionally RViz) against the arm camera.

ros2 launch allo_mrad_ros detect.launch.py [config:=/path/mrad.yaml] [namespace:=arm2]
    [mesh:=/path/station.glb] [pose_source:=topic] [image_transport:=compressed]
    [use_sim_time:=true] [image_topic:=/cam/image_raw] [pose_topic:=...] [sun_topic:=...]
    [sun_strength_topic:=...] [bodies_topic:=...] [log_level:=debug] [rviz:=true]
    [respawn:=true] [respawn_delay:=2.0] [lifecycle:=true] [autostart:=false]

Only the arguments given are forwarded: the parameter file's values hold for the rest
(allo_mrad_ros.ros.launch_arguments). The node's inputs are relative names, so
``namespace:=arm2`` moves inputs and outputs together; camera_info follows the image topic
(its sibling ``camera_info``). RViz is optional: install ros-$ROS_DISTRO-rviz2 to use rviz:=true.

``lifecycle:=true`` starts the managed variant ``mrad_detector_lifecycle`` instead; with
``autostart:=true`` (the default) the launch configures it on start and activates it once it
reaches inactive from configuring, as nav2's lifecycle manager does; ``autostart:=false``
leaves it unconfigured for ``ros2 lifecycle set`` or a lifecycle manager.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler
from launch.conditions import IfCondition
from launch.events import matches_action
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import LifecycleNode, Node
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState
from launch_ros.substitutions import FindPackageShare
from lifecycle_msgs.msg import Transition

from allo_mrad_ros import interface
from allo_mrad_ros.ros import launch_arguments

PACKAGE = "allo_mrad_ros"


def _switch(name: str, default: bool, description: str) -> DeclareLaunchArgument:
    """A true/false launch argument (real launch compares choices exactly)."""
    return DeclareLaunchArgument(
        name,
        default_value=str(default).lower(),
        description=description,
        choices=["true", "false"],
    )


def _autostart(detector: LifecycleNode) -> list:
    """Configure ``detector`` now, and activate it each time a configure succeeds (its
    transition from configuring to inactive; a deactivate, which also ends in inactive, is
    left alone)."""

    def change(transition: int) -> EmitEvent:
        return EmitEvent(
            event=ChangeState(
                lifecycle_node_matcher=matches_action(detector), transition_id=transition
            )
        )

    activate = OnStateTransition(
        target_lifecycle_node=detector,
        start_state="configuring",
        goal_state="inactive",
        entities=[change(Transition.TRANSITION_ACTIVATE)],
    )
    return [RegisterEventHandler(activate), change(Transition.TRANSITION_CONFIGURE)]


def _nodes(context: object) -> list:
    """The node and RViz, with only the launch arguments the user gave (and, for a managed
    node with autostart, the events that configure and activate it)."""
    values = {
        argument.name: LaunchConfiguration(argument.name).perform(context)
        for argument in launch_arguments.ARGUMENTS
    }
    overrides = launch_arguments.parameter_overrides(values)
    config = LaunchConfiguration("config").perform(context)
    namespace = values["namespace"]
    common = dict(
        name=interface.NODE_NAME,
        namespace=namespace,
        output="screen",
        parameters=[config, overrides] if overrides else [config],
        remappings=launch_arguments.remappings(values),
        arguments=launch_arguments.ros_arguments(
            LaunchConfiguration("log_level").perform(context), namespace
        ),
        **launch_arguments.respawn_options(
            LaunchConfiguration("respawn").perform(context),
            LaunchConfiguration("respawn_delay").perform(context),
        ),
    )
    managed = LaunchConfiguration("lifecycle").perform(context) == "true"
    if managed:
        detector = LifecycleNode(package=PACKAGE, executable="mrad_detector_lifecycle", **common)
    else:
        detector = Node(package=PACKAGE, executable="mrad_detector", **common)
    sim_time = {k: v for k, v in overrides.items() if k == "use_sim_time"}
    rviz = Node(
        package="rviz2",
        executable="rviz2",
        name="rviz2",
        namespace=namespace,
        arguments=["-d", PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "mrad.rviz"])],
        parameters=[sim_time] if sim_time else [],
        condition=IfCondition(LaunchConfiguration("rviz")),
    )
    autostart = managed and LaunchConfiguration("autostart").perform(context) == "true"
    return [detector, rviz, *(_autostart(detector) if autostart else [])]


def generate_launch_description() -> LaunchDescription:
    """The launch arguments, then the nodes built from the ones given."""
    arguments = [
        DeclareLaunchArgument(
            "config",
            default_value=PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "mrad.yaml"]),
            description="parameter file of the node",
        ),
        _switch("rviz", False, "also start RViz with the package's view (needs rviz2 installed)"),
        DeclareLaunchArgument(
            "log_level",
            default_value="info",
            description="the node's log severity (its own logger; rcl and the middleware keep "
            "theirs)",
            choices=list(launch_arguments.LOG_LEVELS),
        ),
        _switch("respawn", False, "start the node again when its process ends"),
        _switch("lifecycle", False, "start the managed variant mrad_detector_lifecycle instead"),
        _switch(
            "autostart",
            True,
            "with lifecycle:=true: configure the node on start and activate it "
            "after each successful configure (false: it waits unconfigured)",
        ),
        DeclareLaunchArgument(
            "respawn_delay",
            default_value=launch_arguments.DEFAULT_RESPAWN_DELAY_S,
            description="seconds to wait before starting it again (respawn:=true)",
        ),
    ]
    arguments += [
        DeclareLaunchArgument(
            argument.name,
            default_value=launch_arguments.NOT_GIVEN,
            description=argument.description,
            **({"choices": launch_arguments.launch_choices(argument)} if argument.choices else {}),
        )
        for argument in launch_arguments.ARGUMENTS
    ]
    return LaunchDescription([*arguments, OpaqueFunction(function=_nodes)])
