"""Building and serializing the messages of a bag with a distribution's message definitions."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from rosbags.typesys.store import Typestore

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.render.bodies import DEFAULT_COLOURS
from allo_mrad_ros.sequence import GroundTruthObject
from rosbag_tools.topics import (
    CAMERA_INFO,
    FLOAT32,
    IMAGE,
    MARKER_ADD,
    MARKER_ARRAY,
    MARKER_CUBE,
    MARKER_DELETE,
    MARKER_SPHERE,
    POSE_STAMPED,
    STRING,
    TF_MESSAGE,
    VECTOR3_STAMPED,
    TopicError,
)


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
        """A ``sensor_msgs/Image``: ``rgb8`` for (H, W, 3) uint8, ``mono8`` for (H, W),
        ``mono16`` (little-endian) for (H, W) uint16."""
        array = np.ascontiguousarray(array)
        if array.dtype == np.uint16 and array.ndim == 2:
            height, width = array.shape
            return self.build(
                IMAGE,
                header=self.header(stamp_ns, frame_id),
                height=height,
                width=width,
                encoding="mono16",
                is_bigendian=0,
                step=width * 2,
                data=array.astype("<u2").view(np.uint8).reshape(-1),
            )
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

    def _placement(
        self, msgtype: str, names: tuple[str, str], xyz: Sequence[float], xyzw: Sequence[float]
    ) -> Any:
        """A Transform (translation, rotation) or Pose (position, orientation)."""
        point = (
            "geometry_msgs/msg/Vector3" if names[0] == "translation" else "geometry_msgs/msg/Point"
        )
        return self.build(
            msgtype, **{names[0]: self._point(point, xyz), names[1]: self._quaternion(xyzw)}
        )

    def tf_message(
        self,
        stamp_ns: int,
        parent: str,
        child: str,
        translation: Sequence[float],
        rotation_xyzw: Sequence[float],
    ) -> Any:
        """A ``tf2_msgs/TFMessage`` holding one transform ``parent`` -> ``child``."""
        transform = self._placement(
            "geometry_msgs/msg/Transform", ("translation", "rotation"), translation, rotation_xyzw
        )
        stamped = self.build(
            "geometry_msgs/msg/TransformStamped",
            header=self.header(stamp_ns, parent),
            child_frame_id=child,
            transform=transform,
        )
        return self.build(TF_MESSAGE, transforms=[stamped])

    def pose_stamped(
        self, stamp_ns: int, frame_id: str, pose: tuple[Sequence[float], Sequence[float]]
    ) -> Any:
        """A ``geometry_msgs/PoseStamped`` from ``pose`` = (position, orientation x, y, z, w)."""
        position, orientation_xyzw = pose
        return self.build(
            POSE_STAMPED,
            header=self.header(stamp_ns, frame_id),
            pose=self._placement(
                "geometry_msgs/msg/Pose", ("position", "orientation"), position, orientation_xyzw
            ),
        )

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

    def _sphere_marker(self, header: Any, name: str, action: int, **fields: Any) -> Any:
        return self.build(
            "visualization_msgs/msg/Marker",
            header=header,
            ns=name,
            id=0,
            type=MARKER_SPHERE,
            action=action,
            **fields,
        )

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
                self._sphere_marker(
                    header,
                    name,
                    MARKER_ADD,
                    pose=pose,
                    scale=self._point("geometry_msgs/msg/Vector3", (diameter,) * 3),
                    color=self.build("std_msgs/msg/ColorRGBA", r=r, g=g, b=b, a=1.0),
                )
            )
        for name in deleted:
            markers.append(self._sphere_marker(header, name, MARKER_DELETE))
        return self.build(MARKER_ARRAY, markers=markers)

    def object_markers(
        self, stamp_ns: int, frame_id: str, objects: Sequence[GroundTruthObject]
    ) -> Any:
        """A ``visualization_msgs/MarkerArray``: one ``CUBE`` per ground-truth object, its box
        at ``stamp_ns`` (``ns`` = type, ``id`` = object id, scale = box extents)."""
        header = self.header(stamp_ns, frame_id)
        markers = []
        for item in objects:
            pose = self._placement(
                "geometry_msgs/msg/Pose",
                ("position", "orientation"),
                item.position_at(stamp_ns),
                item.quaternion,
            )
            markers.append(
                self.build(
                    "visualization_msgs/msg/Marker",
                    header=header,
                    ns=item.type,
                    id=int(item.id),
                    type=MARKER_CUBE,
                    action=MARKER_ADD,
                    pose=pose,
                    scale=self._point("geometry_msgs/msg/Vector3", item.size),
                    color=self.build("std_msgs/msg/ColorRGBA", r=1.0, g=0.45, b=0.0, a=0.8),
                )
            )
        return self.build(MARKER_ARRAY, markers=markers)
