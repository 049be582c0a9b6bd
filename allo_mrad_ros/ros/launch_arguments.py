"""The arguments of ``launch/detect.launch.py`` and what each one forwards to the node.

An argument the user did not give stays empty and forwards nothing, so the parameter file
(``config:=my.yaml``) keeps its values: launch defaults never override a config. Plain Python,
no launch import, so the rule is testable without a ROS distro.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from allo_mrad_ros import interface
from allo_mrad_ros.errors import InvalidInput

NOT_GIVEN = ""


class LaunchArgumentError(InvalidInput):
    """A launch argument has a value its node parameter cannot take."""


@dataclass(frozen=True)
class LaunchArgument:
    """One launch argument: a node parameter it sets, or a node input it remaps."""

    name: str
    description: str
    parameter: str = ""
    kind: type = str
    input_topic: str = ""
    # The values a user may give (enumerated arguments); NOT_GIVEN is always allowed.
    choices: tuple[str, ...] = ()


ARGUMENTS: tuple[LaunchArgument, ...] = (
    LaunchArgument("namespace", "namespace of the node (and RViz): one per camera"),
    LaunchArgument(
        "mesh",
        "station CAD model (trimesh-loadable, metres); not given: the parameter file's mesh "
        "(empty there: the package's meshes/station.glb)",
        parameter="mesh",
    ),
    LaunchArgument(
        "pose_source",
        "camera pose from tf (tf2_ros) or topic (PoseStamped); not given: the parameter file's",
        parameter="pose_source",
        choices=("tf", "topic"),
    ),
    LaunchArgument(
        "image_transport",
        "raw (sensor_msgs/Image) or compressed (CompressedImage on <image>/compressed); "
        "not given: the parameter file's",
        parameter="image_transport",
        choices=interface.IMAGE_TRANSPORTS,
    ),
    LaunchArgument(
        "use_sim_time",
        "true: use /clock (replaying a bag with --clock); not given: the parameter file's",
        parameter="use_sim_time",
        kind=bool,
        choices=("true", "false"),
    ),
    LaunchArgument(
        "image_topic",
        "camera image; its camera_info is the sibling topic camera_info (image_transport's rule)",
        input_topic=interface.IMAGE_INPUT,
    ),
    LaunchArgument(
        "pose_topic", "camera pose (pose_source topic)", input_topic=interface.POSE_INPUT
    ),
    LaunchArgument("sun_topic", "Sun direction", input_topic=interface.SUN_DIRECTION_INPUT),
    LaunchArgument("sun_strength_topic", "Sun strength", input_topic=interface.SUN_STRENGTH_INPUT),
    LaunchArgument(
        "bodies_topic", "celestial bodies (MarkerArray)", input_topic=interface.BODIES_INPUT
    ),
)


# Severities of ``--log-level`` (the launch argument ``log_level``).
LOG_LEVELS = ("debug", "info", "warn", "error", "fatal")


def launch_choices(argument: LaunchArgument) -> list[str] | None:
    """The ``choices`` of the declared launch argument (NOT_GIVEN first), or None."""
    if not argument.choices:
        return None
    return [NOT_GIVEN, *argument.choices]


# Seconds before a node that died is started again (launch argument ``respawn_delay``), as
# nav2's launch files wait.
DEFAULT_RESPAWN_DELAY_S = "2.0"


def node_logger_name(namespace: str = "") -> str:
    """The node's logger name: its namespace and name joined by dots, as rcl names it
    (``arm2.mrad_detector`` for ``/arm2/mrad_detector``)."""
    return ".".join([*filter(None, namespace.split("/")), interface.NODE_NAME])


def ros_arguments(log_level: str, namespace: str = "") -> list[str]:
    """The node's ``--ros-args`` for the launch argument ``log_level``.

    The level is set on the node's own logger only (``--log-level mrad_detector:=debug``):
    a bare ``--log-level debug`` would also turn on the debug output of rcl and the
    middleware, hundreds of lines a second that drown the node's own.
    """
    if log_level not in LOG_LEVELS:
        raise LaunchArgumentError(f"launch argument log_level must be one of {list(LOG_LEVELS)}")
    return ["--ros-args", "--log-level", f"{node_logger_name(namespace)}:={log_level}"]


def respawn_options(respawn: str, delay: str) -> dict[str, Any]:
    """launch_ros ``Node``'s ``respawn`` and ``respawn_delay`` for the launch arguments.

    Raises
    ------
    LaunchArgumentError
        For ``respawn`` neither ``true`` nor ``false``, or a delay that is not a number of
        seconds >= 0.
    """
    if respawn not in ("true", "false"):
        raise LaunchArgumentError("launch argument respawn must be true or false")
    try:
        seconds = float(delay)
    except ValueError:
        seconds = -1.0
    if not (seconds >= 0.0 and seconds != float("inf")):
        raise LaunchArgumentError(
            f"launch argument respawn_delay must be a number of seconds >= 0, got {delay!r}"
        )
    return {"respawn": respawn == "true", "respawn_delay": seconds}


def _typed(argument: LaunchArgument, text: str) -> Any:
    if argument.kind is bool:
        lowered = text.strip().lower()
        if lowered not in ("true", "false"):
            raise LaunchArgumentError(f"launch argument {argument.name} must be true or false")
        return lowered == "true"
    return text


def parameter_overrides(values: Mapping[str, str]) -> dict[str, Any]:
    """The node parameters set by launch arguments the user gave (non-empty), typed.

    Raises
    ------
    LaunchArgumentError
        For a boolean argument that is neither ``true`` nor ``false``.
    """
    return {
        argument.parameter: _typed(argument, values[argument.name])
        for argument in ARGUMENTS
        if argument.parameter and values.get(argument.name, NOT_GIVEN) != NOT_GIVEN
    }


def remappings(values: Mapping[str, str]) -> list[tuple[str, str]]:
    """``(node input, topic)`` for every topic argument the user gave.

    The node's inputs are relative names, so a remapping matches inside any namespace.
    """
    return [
        (argument.input_topic, values[argument.name])
        for argument in ARGUMENTS
        if argument.input_topic and values.get(argument.name, NOT_GIVEN) != NOT_GIVEN
    ]
