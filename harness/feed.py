"""A ROS peer for the node: publishes camera inputs and collects the node's outputs.

The integration tests and ``make bench-node`` run the node as its own process
(:func:`allo_mrad_ros.ros.node_process.start_node`) and drive it with a :class:`CameraFeed`
in theirs. Keep DDS on loopback (``config/fastdds_loopback.xml``) when using it.
"""

from __future__ import annotations

import array
import time
from collections import defaultdict
from collections.abc import Callable, Iterable

import cv2
import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Vector3Stamped
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Bool
from visualization_msgs.msg import ImageMarker

from allo_mrad_ros import interface
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import matrix_to_quaternion
from allo_mrad_ros.ros.messages import fill_camera_info, fill_image, stamp_to_ns

IMAGE_OUTPUTS = ("mask", "score", "overlay")
# Every output of the node (``~/<name>``) and its message type.
OUTPUT_TYPES: dict[str, type] = {
    "mask": Image,
    "score": Image,
    "score/camera_info": CameraInfo,
    "overlay": Image,
    "anomaly": Bool,
    "result": DiagnosticArray,
    "regions": ImageMarker,
    "reference": Image,
    "reference/camera_info": CameraInfo,
}


class CameraFeed:
    """Publishes images, camera_info, poses and the sun; records the node's outputs.

    Parameters
    ----------
    intrinsics : CameraIntrinsics
        Camera of the published camera_info.
    frame_id : str
        Frame of images and camera_info.
    keep_messages : bool
        Keep received outputs (else only their arrival times).
    namespace : str
        The node's namespace: inputs are published there, outputs read from there.
    compression : str
        ``""``: raw images; ``"jpeg"`` or ``"png"``: CompressedImage on ``<image>/compressed``.
    outputs : iterable of str
        The image outputs to subscribe to (of ``mask``, ``score``, ``overlay``).
    """

    def __init__(
        self,
        intrinsics: CameraIntrinsics,
        frame_id: str = interface.CAMERA_FRAME,
        keep_messages: bool = True,
        namespace: str = "",
        compression: str = "",
        outputs: tuple[str, ...] = IMAGE_OUTPUTS,
    ) -> None:
        prefix = f"/{namespace.strip('/')}" if namespace.strip("/") else ""
        self.node = rclpy.create_node("mrad_camera_feed", namespace=prefix or "/")
        self.keep_messages = keep_messages
        self.intrinsics = intrinsics
        self.frame_id = frame_id
        self.compression = compression
        sensor = qos_profile_sensor_data
        publish = self.node.create_publisher
        image_topic = f"{prefix}/{interface.IMAGE_INPUT}"
        if compression:
            self.pub_image = publish(
                CompressedImage, image_topic + interface.COMPRESSED_SUFFIX, sensor
            )
        else:
            self.pub_image = publish(Image, image_topic, sensor)
        self.pub_info = publish(CameraInfo, f"{prefix}/{interface.CAMERA_INFO_INPUT}", sensor)
        self.pub_pose = publish(PoseStamped, f"{prefix}/{interface.POSE_INPUT}", 50)
        self.pub_sun = publish(Vector3Stamped, f"{prefix}/{interface.SUN_DIRECTION_INPUT}", 10)
        self.received: dict[str, dict[int, object]] = defaultdict(dict)
        self.arrival: dict[str, dict[int, float]] = defaultdict(dict)
        self.diagnostics: list[DiagnosticArray] = []
        self.anomaly_flags: list[bool] = []
        self.output_prefix = f"{prefix}/{interface.NODE_NAME}"
        self.subscriptions = {
            topic: self.node.create_subscription(
                Image, f"{self.output_prefix}/{topic}", self._recorder(topic), 10
            )
            for topic in outputs
        }
        self.subscriptions["anomaly"] = self.node.create_subscription(
            Bool, f"{self.output_prefix}/anomaly", lambda m: self.anomaly_flags.append(m.data), 10
        )
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        # Several nodes may share /diagnostics: keep this namespace's node only.
        if msg.status and msg.status[0].name.startswith(f"{self.output_prefix[1:]}:"):
            self.diagnostics.append(msg)

    def subscribe(self, topic: str, kind: type = Image) -> None:
        """Also record output ``topic`` (``~/<topic>`` of the node) of message type ``kind``."""
        if topic not in self.subscriptions:
            callback = (
                (lambda m: self.anomaly_flags.append(m.data))
                if kind is Bool
                else self._recorder(topic)
            )
            self.subscriptions[topic] = self.node.create_subscription(
                kind, f"{self.output_prefix}/{topic}", callback, 10
            )

    def set_outputs(self, topics: Iterable[str]) -> None:
        """Subscribe to ``~/mask`` and ``topics`` (names of :data:`OUTPUT_TYPES`) only."""
        wanted = {"mask", *topics}
        for topic in list(self.subscriptions):
            if topic not in wanted:
                self.unsubscribe(topic)
        for topic in sorted(wanted):
            self.subscribe(topic, OUTPUT_TYPES[topic])

    def unsubscribe(self, topic: str) -> None:
        """Stop recording output ``topic``."""
        subscription = self.subscriptions.pop(topic, None)
        if subscription is not None:
            self.node.destroy_subscription(subscription)

    def _recorder(self, topic: str) -> Callable[[Image], None]:
        def record(msg: Image) -> None:
            stamp = stamp_to_ns(msg.header.stamp)
            self.arrival[topic][stamp] = time.time()
            if self.keep_messages:
                self.received[topic][stamp] = msg

        return record

    def spin(self, seconds: float) -> None:
        """Process callbacks for ``seconds``."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(self.node, timeout_sec=0.02)

    def wait_for(self, condition: Callable[[], bool], timeout: float) -> bool:
        """Spin until ``condition()`` holds or ``timeout`` seconds pass; return it."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if condition():
                return True
            rclpy.spin_once(self.node, timeout_sec=0.05)
        return condition()

    def wait_for_node(self, timeout: float = 30.0) -> bool:
        """Wait until the node is ready for the first image: both sides of the image and
        the camera_info topics matched. This side's publishers have matched the node's
        subscriptions (else a best-effort sample goes to nobody), and the node's
        subscriptions have matched a publisher (what its ``/diagnostics`` report; this side's
        count can rise first, and an image sent then is dropped by DDS)."""
        seen = len(self.diagnostics)  # an earlier node's reports do not count

        def ready() -> bool:
            ours = (self.pub_image, self.pub_info)
            if any(p.get_subscription_count() == 0 for p in ours) or len(self.diagnostics) == seen:
                return False
            values = self.diagnostic_values()
            return all(
                int(values.get(f"{name}_publishers", 0)) > 0 for name in ("image", "camera_info")
            )

        return self.wait_for(ready, timeout)

    def camera_info(self) -> CameraInfo:
        """CameraInfo of the current intrinsics (no distortion)."""
        return fill_camera_info(CameraInfo(), self.intrinsics, self.frame_id)

    def publish_frame(
        self,
        stamp_ns: int,
        rgb: np.ndarray | None,
        pose: np.ndarray | None,
        sun: tuple[float, float, float] = (0.3, -0.5, 0.8),
        image: Image | None = None,
    ) -> None:
        """Publish pose (unless None), sun, camera_info and the image with one stamp."""
        sec, nanosec = divmod(stamp_ns, 1_000_000_000)
        info = self.camera_info()
        info.header.stamp.sec, info.header.stamp.nanosec = sec, nanosec
        if pose is not None:
            msg = PoseStamped()
            msg.header.stamp = info.header.stamp
            msg.header.frame_id = interface.STATION_FRAME
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = pose[:3, 3].tolist()
            q = matrix_to_quaternion(pose[:3, :3])
            o = msg.pose.orientation
            o.x, o.y, o.z, o.w = q.tolist()
            self.pub_pose.publish(msg)
        sun_msg = Vector3Stamped()
        sun_msg.header.stamp = info.header.stamp
        sun_msg.header.frame_id = interface.STATION_FRAME
        sun_msg.vector.x, sun_msg.vector.y, sun_msg.vector.z = sun
        self.pub_sun.publish(sun_msg)
        self.pub_info.publish(info)
        if image is None and self.compression:
            image = compress_image(rgb, self.compression)
            image.header = info.header
        elif image is None:
            image = fill_image(Image(), info.header, rgb, interface.RGB8)
            image.header.frame_id = self.frame_id
        else:
            image.header.stamp = info.header.stamp
        self.pub_image.publish(image)

    def diagnostic_values(self) -> dict[str, str]:
        """Key/values of the latest /diagnostics status."""
        if not self.diagnostics:
            return {}
        status = self.diagnostics[-1].status[0]
        return {kv.key: kv.value for kv in status.values}


def compress_image(rgb: np.ndarray, compression: str) -> CompressedImage:
    """A CompressedImage of an RGB array as image_transport's ``compressed`` publisher makes it."""
    ok, data = cv2.imencode(f".{compression}", np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise ValueError(f"cannot encode the image as {compression}")
    msg = CompressedImage()
    msg.format = f"rgb8; {compression} compressed bgr8"
    buffer = array.array("B")
    buffer.frombytes(data.tobytes())
    msg.data = buffer
    return msg
