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
``tf_static``              ``/tf_static``                      tf2_msgs/TFMessage
=========================  ==================================  ============================

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
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from allo_mrad_ros import interface
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.render.bodies import DEFAULT_COLOURS

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

DISTROS: dict[str, tuple[Stores, int]] = {
    # rosbag2 metadata version per distribution. rosbags writes versions 8 and 9 only, so
    # Humble (whose recorder writes version 5) gets 8: its message definitions are Humble's,
    # and Humble's `ros2 bag` reads such a bag after `ros2 bag reindex` if it balks at the
    # metadata version.
    "humble": (Stores.ROS2_HUMBLE, 8),
    "jazzy": (Stores.ROS2_JAZZY, 9),
    "kilted": (Stores.ROS2_KILTED, 9),
}
"""Supported distributions: name -> (rosbags typestore, rosbag2 metadata version)."""

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
    """Return the rosbags typestore of a distribution name (``humble``, ``jazzy``, ``kilted``).

    Raises
    ------
    TopicError
        For an unsupported distribution.
    """
    if distro not in DISTROS:
        raise TopicError(f"unsupported ROS distribution {distro!r}; choose from {sorted(DISTROS)}")
    return get_typestore(DISTROS[distro][0])


def split_stamp(stamp_ns: int) -> tuple[int, int]:
    """Split nanoseconds into ``builtin_interfaces/Time`` seconds and nanoseconds."""
    if stamp_ns < 0 or stamp_ns >= 2**31 * 10**9:
        raise TopicError(f"stamp {stamp_ns} ns does not fit builtin_interfaces/Time")
    return int(stamp_ns // 10**9), int(stamp_ns % 10**9)


_NUMPY_TYPES = {
    "bool": np.bool_,
    "byte": np.uint8,
    "char": np.uint8,
    "int8": np.int8,
    "uint8": np.uint8,
    "int16": np.int16,
    "uint16": np.uint16,
    "int32": np.int32,
    "uint32": np.uint32,
    "int64": np.int64,
    "uint64": np.uint64,
    "float32": np.float32,
    "float64": np.float64,
}


class MessageFactory:
    """Build rosbags messages of one distribution, filling unnamed fields with defaults.

    Definitions differ between distributions (fields added over time), so messages are built
    from the typestore's own field list: the caller names the fields it cares about and the
    rest get the ROS default (zero, empty string, empty sequence).

    Parameters
    ----------
    typestore : Typestore
        The distribution's typestore (:func:`typestore_for`).
    """

    def __init__(self, typestore: Typestore) -> None:
        self.typestore = typestore

    def _default(self, desc: tuple[Any, Any]) -> object:
        kind, detail = desc
        if kind == 1:  # base type
            name = detail[0]
            return "" if name in ("string", "wstring") else _NUMPY_TYPES[name](0).item()
        if kind == 2:  # nested message
            return self.build(detail)
        element, length = detail
        if element[0] == 1 and element[1][0] in _NUMPY_TYPES:
            dtype = _NUMPY_TYPES[element[1][0]]
            return np.zeros(length if kind == 3 else 0, dtype=dtype)
        if kind == 3:
            return [self._default(element) for _ in range(length)]
        return []

    def build(self, msgtype: str, **values: object) -> Any:
        """Return a message of ``msgtype`` with ``values`` and defaults elsewhere.

        Raises
        ------
        TopicError
            If the type is unknown to the typestore or a value names no field.
        """
        try:
            _, field_list = self.typestore.fielddefs[msgtype]
            cls = self.typestore.types[msgtype]
        except KeyError:
            raise TopicError(f"message type {msgtype} is not in the typestore") from None
        names = [name for name, _ in field_list]
        unknown = sorted(set(values) - set(names))
        if unknown:
            raise TopicError(f"{msgtype} has no field(s) {unknown}")
        args = {
            name: values[name] if name in values else self._default(desc)
            for name, desc in field_list
        }
        return cls(**args)

    def serialize(self, message: object, msgtype: str) -> bytes:
        """CDR bytes of a message, as rosbag2 stores them."""
        return bytes(self.typestore.serialize_cdr(message, msgtype))

    # -------------------------------------------------------------- message builders
    def header(self, stamp_ns: int, frame_id: str) -> Any:
        """A ``std_msgs/Header``."""
        sec, nanosec = split_stamp(stamp_ns)
        stamp = self.build("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)
        return self.build("std_msgs/msg/Header", stamp=stamp, frame_id=frame_id)

    def image(self, stamp_ns: int, frame_id: str, array: np.ndarray) -> Any:
        """A ``sensor_msgs/Image``: ``rgb8`` for (H, W, 3) uint8, ``mono8`` for (H, W)."""
        array = np.ascontiguousarray(array)
        if array.dtype != np.uint8 or array.ndim not in (2, 3):
            raise TopicError(f"image must be uint8 (H, W[, 3]), got {array.dtype} {array.shape}")
        if array.ndim == 3 and array.shape[2] != 3:
            raise TopicError(f"colour image must have 3 channels, got {array.shape}")
        height, width = array.shape[:2]
        channels = 1 if array.ndim == 2 else 3
        return self.build(
            IMAGE,
            header=self.header(stamp_ns, frame_id),
            height=height,
            width=width,
            encoding="mono8" if channels == 1 else "rgb8",
            is_bigendian=0,
            step=width * channels,
            data=array.reshape(-1),
        )

    def camera_info(self, stamp_ns: int, frame_id: str, camera: CameraIntrinsics) -> Any:
        """A ``sensor_msgs/CameraInfo``: plumb_bob with zero distortion, K and P from ``camera``."""
        k = camera.matrix
        p = np.hstack([k, np.zeros((3, 1))])
        return self.build(
            CAMERA_INFO,
            header=self.header(stamp_ns, frame_id),
            height=camera.height,
            width=camera.width,
            distortion_model="plumb_bob",
            d=np.zeros(5, dtype=np.float64),
            k=k.reshape(-1).astype(np.float64),
            r=np.eye(3).reshape(-1),
            p=p.reshape(-1).astype(np.float64),
        )

    def _point(self, msgtype: str, xyz: Sequence[float]) -> Any:
        x, y, z = (float(v) for v in xyz)
        return self.build(msgtype, x=x, y=y, z=z)

    def _quaternion(self, xyzw: Sequence[float]) -> Any:
        x, y, z, w = (float(v) for v in xyzw)
        return self.build("geometry_msgs/msg/Quaternion", x=x, y=y, z=z, w=w)

    def tf_message(
        self,
        stamp_ns: int,
        parent: str,
        child: str,
        translation: Sequence[float],
        rotation_xyzw: Sequence[float],
    ) -> Any:
        """A ``tf2_msgs/TFMessage`` holding one transform ``parent`` -> ``child``."""
        transform = self.build(
            "geometry_msgs/msg/Transform",
            translation=self._point("geometry_msgs/msg/Vector3", translation),
            rotation=self._quaternion(rotation_xyzw),
        )
        stamped = self.build(
            "geometry_msgs/msg/TransformStamped",
            header=self.header(stamp_ns, parent),
            child_frame_id=child,
            transform=transform,
        )
        return self.build(TF_MESSAGE, transforms=[stamped])

    def pose_stamped(
        self,
        stamp_ns: int,
        frame_id: str,
        position: Sequence[float],
        orientation_xyzw: Sequence[float],
    ) -> Any:
        """A ``geometry_msgs/PoseStamped``."""
        pose = self.build(
            "geometry_msgs/msg/Pose",
            position=self._point("geometry_msgs/msg/Point", position),
            orientation=self._quaternion(orientation_xyzw),
        )
        return self.build(POSE_STAMPED, header=self.header(stamp_ns, frame_id), pose=pose)

    def vector3_stamped(self, stamp_ns: int, frame_id: str, vector: Sequence[float]) -> Any:
        """A ``geometry_msgs/Vector3Stamped``."""
        return self.build(
            VECTOR3_STAMPED,
            header=self.header(stamp_ns, frame_id),
            vector=self._point("geometry_msgs/msg/Vector3", vector),
        )

    def float32(self, value: float) -> Any:
        """A ``std_msgs/Float32``."""
        return self.build(FLOAT32, data=float(value))

    def string(self, text: str) -> Any:
        """A ``std_msgs/String``."""
        return self.build(STRING, data=text)

    def body_markers(
        self,
        stamp_ns: int,
        frame_id: str,
        bodies: Sequence[tuple[str, Sequence[float], float]],
        deleted: Iterable[str] = (),
    ) -> Any:
        """A ``visualization_msgs/MarkerArray``: one sphere per body, a delete per gone body.

        Parameters
        ----------
        stamp_ns : int
            Header stamp.
        frame_id : str
            The station frame.
        bodies : sequence of (name, centre, radius)
            Bodies present in this frame.
        deleted : iterable of str
            Names of bodies shown before and absent now.
        """
        markers = []
        header = self.header(stamp_ns, frame_id)
        for name, centre, radius in bodies:
            if not radius > 0:
                raise TopicError(f"body {name!r}: radius must be positive, got {radius!r}")
            r, g, b = DEFAULT_COLOURS.get(name.lower(), (0.5, 0.5, 0.5))
            diameter = 2.0 * float(radius)
            pose = self.build(
                "geometry_msgs/msg/Pose",
                position=self._point("geometry_msgs/msg/Point", centre),
                orientation=self._quaternion((0.0, 0.0, 0.0, 1.0)),
            )
            markers.append(
                self.build(
                    "visualization_msgs/msg/Marker",
                    header=header,
                    ns=name,
                    id=0,
                    type=MARKER_SPHERE,
                    action=MARKER_ADD,
                    pose=pose,
                    scale=self._point("geometry_msgs/msg/Vector3", (diameter,) * 3),
                    color=self.build("std_msgs/msg/ColorRGBA", r=r, g=g, b=b, a=1.0),
                )
            )
        for name in deleted:
            markers.append(
                self.build(
                    "visualization_msgs/msg/Marker",
                    header=header,
                    ns=name,
                    id=0,
                    type=MARKER_SPHERE,
                    action=MARKER_DELETE,
                )
            )
        return self.build(MARKER_ARRAY, markers=markers)
