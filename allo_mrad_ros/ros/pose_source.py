"""Where the camera pose at an image stamp comes from: TF (tf2_ros) or a PoseStamped topic."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.qos import QoSProfile

from allo_mrad_ros import interface
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
        if kind == "tf" and not has_tf:
            self._logger.error(
                "pose_source is 'tf' but tf2_ros is not installed (pip install without a ROS "
                f"distro); using pose_source 'topic' on {interface.POSE_TOPIC} instead"
            )
            kind = "topic"
        self.kind = kind
        if kind == "tf":
            import tf2_ros

            self._tf_buffer = tf2_ros.Buffer()
            self._tf_listener = tf2_ros.TransformListener(self._tf_buffer, node)
        else:
            if not has_tf:
                self._logger.info(
                    f"tf2_ros is not installed: camera poses come from {interface.POSE_TOPIC} "
                    "(geometry_msgs/PoseStamped, pose_source 'topic')"
                )
            node.create_subscription(PoseStamped, interface.POSE_TOPIC, self._on_pose, state_qos)

    def _on_pose(self, msg: PoseStamped) -> None:
        try:
            self._poses.add(
                messages.stamp_to_ns(msg.header.stamp), messages.pose_to_matrix(msg.pose)
            )
        except MessageError as error:
            self._report(error)

    def lookup(self, header: Any, tolerance_s: float) -> np.ndarray | None:
        """The pose at ``header``'s stamp, or None (after waiting up to ``tolerance_s``)."""
        if self._tf_buffer is not None:
            return self._lookup_tf(header, tolerance_s)
        stamp_ns = messages.stamp_to_ns(header.stamp)
        # Topics arrive in no guaranteed order: give the pose of this stamp a moment,
        # as tf2's lookup with a timeout does.
        deadline = time.monotonic() + tolerance_s
        pose = self._poses.nearest(stamp_ns, int(tolerance_s * 1e9))
        while pose is None and time.monotonic() < deadline:
            time.sleep(0.002)
            pose = self._poses.nearest(stamp_ns, int(tolerance_s * 1e9))
        return pose

    def _lookup_tf(self, header: Any, timeout_s: float) -> np.ndarray | None:
        import tf2_ros
        from rclpy.duration import Duration
        from rclpy.time import Time

        try:
            transform = self._tf_buffer.lookup_transform(
                self._station_frame,
                self._camera_frame or header.frame_id,
                Time.from_msg(header.stamp),
                timeout=Duration(seconds=timeout_s),
            )
        except (
            tf2_ros.LookupException,
            tf2_ros.ConnectivityException,
            tf2_ros.ExtrapolationException,
        ) as error:
            self._logger.debug(f"TF lookup failed: {error}")
            return None
        return messages.transform_to_matrix(transform.transform)
