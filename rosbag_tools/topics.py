"""Topic names and message construction shared by the bag writer, the player and the node.

Every frame of a sequence becomes one message on each of these topics, all stamped with the
frame's ``stamp_ns`` (header stamp and bag time alike):

=========================  ==================================  ============================
key (``TopicNames``)       default topic                       type
=========================  ==================================  ============================
``image``                  ``/arm_camera/image_raw``           sensor_msgs/Image, rgb8
``camera_info``            ``/arm_camera/camera_info``         sensor_msgs/CameraInfo
``tf``                     ``/tf``                             tf2_msgs/TFMessage
``pose``                   ``/arm_camera/pose``                geometry_msgs/PoseStamped
``sun_direction``          ``/allo/sun_direction``             geometry_msgs/Vector3Stamped
``sun_strength``           ``/allo/sun_strength``              std_msgs/Float32
``bodies``                 ``/allo/celestial_bodies``          visualization_msgs/MarkerArray
``mask``                   ``/allo/ground_truth/mask``         sensor_msgs/Image, mono8
``label``                  ``/allo/ground_truth/label``        std_msgs/String
``instances``              ``/allo/ground_truth/instances``    sensor_msgs/Image, mono16
``objects``                ``/allo/ground_truth/objects``      visualization_msgs/MarkerArray
``tf_static``              ``/tf_static``                      tf2_msgs/TFMessage
=========================  ==================================  ============================

``instances`` and ``objects`` are written for sequences of format version 2 only (those with
an objects table): the instance mask of every frame that has one (each pixel the id of the
object it shows, 0 none), and one ``CUBE`` marker per object of the table at the frame's
stamp (``ns`` = object type, ``id`` = object id, pose = its box centre and orientation at
that time, scale = the box's extents), whether in view or not. The whole table, with the
velocities and reference times, is in the bag's custom data (``allo.objects``, the text of
``objects.csv``).

Frame ids: images, camera info and masks carry the camera optical frame of
``sequence.yaml``; the pose, the TF transform (parent station, child camera), the Sun
direction and the body markers carry the station frame.

``/tf_static`` is written only when asked for (``static_parent``): a sequence knows a single
transform, the camera pose, and it changes every frame, so it belongs on ``/tf``. The
optional static transform is an identity from a frame of the user's choice (``world``,
``map``) to the station frame, for RViz setups whose fixed frame is not the station.

Celestial bodies are ``SPHERE`` markers, one per body, ``ns`` = body name (``earth``,
``moon``), ``id`` 0, position = centre, scale = diameter in all three axes, in the station
frame. A body that was drawn in the previous frame and is absent from this one gets a
``DELETE`` marker, so RViz drops it; readers take the ``ADD`` spheres and ignore the rest.
A frame without bodies still gets a (possibly empty) array, so every topic has one message
per frame. Frames without a ground-truth mask get no mask message.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, fields

from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from allo_mrad_ros import interface
from allo_mrad_ros.errors import InvalidInput

IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
VECTOR3_STAMPED = "geometry_msgs/msg/Vector3Stamped"
FLOAT32 = "std_msgs/msg/Float32"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
STRING = "std_msgs/msg/String"

# visualization_msgs/Marker constants (the same in every ROS 2 distribution).
MARKER_SPHERE = interface.MARKER_SPHERE
MARKER_ADD = interface.MARKER_ADD
MARKER_DELETE = interface.MARKER_DELETE
MARKER_CUBE = 1

DISTROS: dict[str, tuple[Stores, int]] = {
    # rosbag2 metadata version rosbags writes per distribution (it writes 8 and 9 only).
    "humble": (Stores.ROS2_HUMBLE, 8),
    "jazzy": (Stores.ROS2_JAZZY, 9),
    "kilted": (Stores.ROS2_KILTED, 9),
}
"""Supported distributions: name -> (rosbags typestore, rosbag2 metadata version written)."""

RECORDER_VERSIONS: dict[str, int] = {"humble": 5, "jazzy": 9, "kilted": 9}
"""The metadata version each distribution's own recorder writes: ``metadata.yaml`` is
rewritten to it after writing where it is older than what rosbags wrote (Humble: 5)."""

DEFAULT_DISTRO = "kilted"

_TOPIC_NAME = re.compile(r"^/?[A-Za-z~{][A-Za-z0-9_{}~]*(/[A-Za-z0-9_{}][A-Za-z0-9_{}]*)*$")


class TopicError(InvalidInput):
    """A topic name, distribution or message value is invalid."""


@dataclass(frozen=True)
class TopicNames:
    """Topic name per role; every field is a ROS 2 topic name.

    Raises
    ------
    TopicError
        If a name is not a valid ROS 2 topic name or two roles share a name.
    """

    image: str = interface.IMAGE_TOPIC
    camera_info: str = interface.CAMERA_INFO_TOPIC
    tf: str = interface.TF_TOPIC
    tf_static: str = interface.TF_STATIC_TOPIC
    pose: str = interface.POSE_TOPIC
    sun_direction: str = interface.SUN_DIRECTION_TOPIC
    sun_strength: str = interface.SUN_STRENGTH_TOPIC
    bodies: str = interface.BODIES_TOPIC
    mask: str = interface.MASK_TOPIC
    label: str = interface.LABEL_TOPIC
    instances: str = interface.INSTANCES_TOPIC
    objects: str = interface.OBJECTS_TOPIC

    def __post_init__(self) -> None:
        seen: dict[str, str] = {}
        for key, name in self.as_dict().items():
            if not isinstance(name, str) or not _TOPIC_NAME.match(name) or "//" in name:
                raise TopicError(f"topic {key}: {name!r} is not a valid ROS 2 topic name")
            if name in seen:
                raise TopicError(f"topics {seen[name]} and {key} share the name {name!r}")
            seen[name] = key

    def as_dict(self) -> dict[str, str]:
        """Role -> topic name."""
        return asdict(self)

    @classmethod
    def roles(cls) -> tuple[str, ...]:
        """The role names, in declaration order."""
        return tuple(f.name for f in fields(cls))

    def replace(self, changes: Mapping[str, str]) -> TopicNames:
        """Return a copy with some topics renamed.

        Parameters
        ----------
        changes : Mapping[str, str]
            Role (a field name) -> new topic name.

        Raises
        ------
        TopicError
            For an unknown role or an invalid name.
        """
        unknown = sorted(set(changes) - set(self.roles()))
        if unknown:
            raise TopicError(f"unknown topic role(s) {unknown}; choose from {list(self.roles())}")
        return TopicNames(**{**self.as_dict(), **changes})

    @classmethod
    def from_assignments(
        cls, assignments: Iterable[str], base: TopicNames | None = None
    ) -> TopicNames:
        """Parse ``role=/topic/name`` strings (the CLI's ``--topic`` values).

        Returns
        -------
        TopicNames
        """
        changes = {}
        for text in assignments:
            role, sep, name = text.partition("=")
            if not sep or not role.strip():
                raise TopicError(f"--topic expects ROLE=NAME, got {text!r}")
            changes[role.strip()] = name.strip()
        return (base or DEFAULT_TOPICS).replace(changes)


DEFAULT_TOPICS = TopicNames()


def typestore_for(distro: str) -> Typestore:
    """The rosbags typestore of ``humble``, ``jazzy`` or ``kilted`` (else TopicError)."""
    if distro not in DISTROS:
        raise TopicError(f"unsupported ROS distribution {distro!r}; choose from {sorted(DISTROS)}")
    return get_typestore(DISTROS[distro][0])
