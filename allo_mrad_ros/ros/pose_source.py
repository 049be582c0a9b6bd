"""Where the camera pose at an image stamp comes from: TF (tf2_ros) or a PoseStamped topic.

Stamped inputs in another frame than ``station_frame`` (a PoseStamped, the Sun's
Vector3Stamped, body markers) are transformed through TF where tf2_ros is installed, and
otherwise rejected with a counted reason (``errors_<what>_frame``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.qos import QoSProfile

from allo_mrad_ros import interface
from allo_mrad_ros.render import CelestialBody
from allo_mrad_ros.ros import messages
from allo_mrad_ros.ros.buffers import StampedBuffer
from allo_mrad_ros.ros.messages import MessageError


def tf2_available() -> bool:
    """Whether tf2_ros can be imported (a ROS distro install; not the pip wheels)."""
    try:
        import tf2_ros  # noqa: F401
    except ImportError:
        return False
    return True


class PoseSource:
    """Looks up ``T_station_camera`` at an image's stamp.

    Parameters
    ----------
    node : rclpy.node.Node
        The node that owns the subscription or the TF listener.
    kind : {"tf", "topic"}
        Requested source; ``tf`` falls back to ``topic`` (loudly) without tf2_ros.
    station_frame, camera_frame : str
        TF frames (``camera_frame`` empty: the image's ``frame_id``).
    state_qos : QoSProfile
        QoS of the pose topic.
    report : callable
        Receives a :class:`~allo_mrad_ros.ros.messages.MessageError` for a bad pose message.
    """

    def __init__(
        self,
        node: Node,
        kind: str,
        station_frame: str,
        camera_frame: str,
        state_qos: QoSProfile,
        report: Callable[[MessageError], None],
    ) -> None:
        self._logger = node.get_logger()
        self._station_frame = station_frame
        self._camera_frame = camera_frame
        self._report = report
        self._poses: StampedBuffer[np.ndarray] = StampedBuffer(512)
        self._tf_buffer = None
        has_tf = tf2_available()
        pose_topic = node.resolve_topic_name(interface.POSE_INPUT)
        if kind == "tf" and not has_tf:
            self._logger.error(
                "pose_source is 'tf' but tf2_ros is not installed (pip install without a ROS "
                f"distro); using pose_source 'topic' on {pose_topic} instead"
            )
            kind = "topic"
        self.kind = kind
        if has_tf:
            import tf2_ros

            self._tf_buffer = tf2_ros.Buffer()
            self._tf_listener = tf2_ros.TransformListener(self._tf_buffer, node)
        if kind == "topic" and not has_tf:
            self._logger.info(
                f"tf2_ros is not installed: camera poses come from {pose_topic} "
                "(geometry_msgs/PoseStamped, pose_source 'topic')"
            )
        self._node, self._state_qos = node, state_qos
        self._subscription = None
        self.set_active(True)

    def set_active(self, active: bool) -> None:
        """Subscribe to the pose topic (``topic`` source) or not: the node drops it while no
        output is subscribed. TF keeps listening (its buffer needs the history)."""
        if self.kind != "topic":
            return
        if active and self._subscription is None:
            self._subscription = self._node.create_subscription(
                PoseStamped, interface.POSE_INPUT, self._on_pose, self._state_qos
            )
        elif not active and self._subscription is not None:
            self._node.destroy_subscription(self._subscription)
            self._subscription = None

    def station_from(self, header: Any, what: str) -> np.ndarray:
        """``T_station_frame`` for ``header.frame_id`` at its stamp (identity for the station).

        Raises
        ------
        MessageError
            Cause ``<what>_frame`` when the frame is not the station's and TF cannot give it.
        """
        frame_id = str(header.frame_id)
        if frame_id == self._station_frame:
            return np.eye(4)
        transform = None
        if self._tf_buffer is not None and frame_id:
            transform = self._transform(frame_id, header.stamp, 0.0)
        if transform is None:
            how = "no TF transform to it" if self._tf_buffer is not None else "tf2_ros absent"
            raise MessageError(
                f"{what}_frame",
                f"{what} message in frame {frame_id!r}, not station_frame "
                f"{self._station_frame!r} ({how}); message ignored",
            )
        return transform

    def in_station(self, header: Any, direction: np.ndarray, what: str) -> np.ndarray:
        """A direction of frame ``header.frame_id`` in the station frame (raises MessageError)."""
        return self.station_from(header, what)[:3, :3] @ direction

    def bodies_in_station(
        self, markers: list, bodies: tuple[CelestialBody, ...]
    ) -> tuple[CelestialBody, ...]:
        """Bodies of ``markers_to_bodies(markers)`` with centres in the station frame."""
        headers = {
            str(m.ns): m.header
            for m in markers
            if int(m.type) == interface.MARKER_SPHERE
            and int(m.action) in (interface.MARKER_ADD, interface.MARKER_MODIFY)
        }
        moved = []
        for body in bodies:
            transform = self.station_from(headers[body.name], "bodies")
            centre = transform[:3, :3] @ np.asarray(body.centre, dtype=np.float64)
            centre = centre + transform[:3, 3]
            moved.append(dataclasses.replace(body, centre=tuple(float(c) for c in centre)))
        return tuple(moved)

    def _on_pose(self, msg: PoseStamped) -> None:
        try:
            pose = self.station_from(msg.header, "pose") @ messages.pose_to_matrix(msg.pose)
            self._poses.add(messages.stamp_to_ns(msg.header.stamp), pose)
        except MessageError as error:
            self._report(error)

    def lookup(self, header: Any, tolerance_s: float, tf_timeout_s: float) -> np.ndarray | None:
        """The pose at ``header``'s stamp, or None.

        TF: waits up to ``tf_timeout_s`` for the transform. Topic: the pose stamped within
        ``tolerance_s``, waiting up to ``tf_timeout_s`` (at least ``tolerance_s``) for it to
        arrive: on a loaded machine the pose callback can run well after the image's.
        """
        if self.kind == "tf":
            frame_id = self._camera_frame or str(header.frame_id)
            if not frame_id or frame_id.startswith("/"):
                why = "is empty" if not frame_id else "starts with '/', which tf2 refuses"
                raise MessageError(
                    "frame_id",
                    f"image frame_id {frame_id!r} {why}: no camera pose from TF (fix the "
                    "camera driver's frame_id or set camera_frame); frame skipped",
                )
            return self._transform(frame_id, header.stamp, tf_timeout_s)
        stamp_ns = messages.stamp_to_ns(header.stamp)
        # Topics arrive in no guaranteed order: give the pose of this stamp a moment,
        # as tf2's lookup with a timeout does.
        deadline = time.monotonic() + max(tolerance_s, tf_timeout_s)
        pose = self._poses.nearest(stamp_ns, int(tolerance_s * 1e9))
        while pose is None and time.monotonic() < deadline:
            time.sleep(0.002)
            pose = self._poses.nearest(stamp_ns, int(tolerance_s * 1e9))
        return pose

    def _transform(self, frame_id: str, stamp: Any, timeout_s: float) -> np.ndarray | None:
        """``T_station_frame`` from TF at ``stamp``, or None (waiting up to ``timeout_s``)."""
        import tf2_ros
        from rclpy.duration import Duration
        from rclpy.time import Time

        # TransformException is the base of every tf2 lookup error (InvalidArgumentException
        # for a '/'-prefixed or empty frame id included).
        failures = tuple(
            getattr(tf2_ros, name)
            for name in (
                "TransformException",
                "LookupException",
                "ConnectivityException",
                "ExtrapolationException",
                "InvalidArgumentException",
            )
            if hasattr(tf2_ros, name)
        )
        try:
            transform = self._tf_buffer.lookup_transform(
                self._station_frame,
                frame_id,
                Time.from_msg(stamp),
                timeout=Duration(seconds=timeout_s),
            )
        except failures as error:
            self._logger.debug(f"TF lookup failed: {error}")
            return None
        return messages.transform_to_matrix(transform.transform)
