"""What ``mrad_detector`` receives, and when it listens at all.

:class:`NodeInputs` holds the node's input side: its subscriptions, their callbacks and what
the callbacks keep. The image, its camera_info, the Sun direction and the pose topic are
subscribed only while an output has a subscriber, as image_pipeline nodes do; the Sun
strength and the celestial bodies stay subscribed while the node is built. A callback only
stores the newest message (:class:`.buffers.LatestSlot` for images,
:class:`.buffers.StampedBuffer` for camera_infos and Sun directions), so an input never waits
for processing. The processing threads read it back through :meth:`NodeInputs.snapshot`
(the camera_info paired with the image by stamp) and :meth:`NodeInputs.view_of` (pose and
lighting at the image stamp).

The node declares the parameters and runs the lifecycle: it resolves the topic names, calls
:meth:`NodeInputs.open` when it builds its outputs, diagnostics and pose source, and hands
each accepted parameter change to :meth:`NodeInputs.configure`.
"""

from __future__ import annotations

import copy
import threading
import time
from collections.abc import Callable, Mapping

import numpy as np
from geometry_msgs.msg import Vector3Stamped
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.subscription import Subscription
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Float32
from visualization_msgs.msg import MarkerArray

from allo_mrad_ros import interface
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.ros import messages
from allo_mrad_ros.ros.buffers import LatestSlot, StampedBuffer
from allo_mrad_ros.ros.diagnostics import Diagnostics
from allo_mrad_ros.ros.messages import MessageError
from allo_mrad_ros.ros.parameters import NodeConfig
from allo_mrad_ros.ros.pose_source import PoseSource
from allo_mrad_ros.ros.rclpy_compat import message_info_callback
from allo_mrad_ros.ros.worker import Arrival, Snapshot
from allo_mrad_ros.view import View

# Longest wait of the processing thread for the camera_info of an image's stamp: the two
# topics arrive in no guaranteed order.
CAMERA_INFO_WAIT_S = 0.5
# Images the middleware keeps until the node takes them: the newest only, so a node short of
# CPU takes the newest frame, not the oldest of a queue (sensor-data QoS keeps 5);
# qos_overrides.<topic>.subscription.depth keeps more. camera_info keeps sensor-data's 5: an
# image is paired with the camera_info of its own stamp, which a queue of one loses whenever
# the next camera_info arrives before the node has taken it (under load, measured).
IMAGE_DEPTH = 1


class NodeInputs:
    """The node's input subscriptions and the state their callbacks keep.

    Parameters
    ----------
    node : rclpy.node.Node
        Owns the subscriptions; its logger, clock and context are used.
    config : NodeConfig
        The settings in force until :meth:`configure` replaces them.
    wanted : callable
        Whether any output has a subscriber now; while none has, no input is needed.
    overriding : callable
        The QoS overriding options of the image and camera_info subscriptions.

    Attributes
    ----------
    images : LatestSlot
        The newest ``(image message, monotonic receive time)``, for the processing threads.
    subscriptions : list
        The Sun direction, image and camera_info subscriptions; empty while unsubscribed.
    pose_source : PoseSource or None
        Set by the node once it has one: moves the Sun and the bodies into the station
        frame, looks the camera pose up, and its topic is subscribed with the inputs.
    """

    def __init__(
        self,
        node: Node,
        config: NodeConfig,
        wanted: Callable[[], bool],
        overriding: Callable[[], QoSOverridingOptions],
    ) -> None:
        self._node = node
        self._wanted = wanted
        self._overriding = overriding
        self._lock = threading.Lock()
        self._config = config
        self.images: LatestSlot[tuple[Image | CompressedImage, float]] = LatestSlot()
        self._intrinsics: CameraIntrinsics | None = None
        # The stamp of the first valid camera_info the subscription of now has given (None:
        # none yet). An image without its camera_info stamped before it (or before any) is
        # the start-up state, not an input error: the image and camera_info subscriptions are
        # matched apart by discovery, at the node's start and at each new subscription when
        # an output's subscriber returns.
        self._first_info_ns: int | None = None
        # Valid camera_infos by stamp: (intrinsics, frame_id, message), paired with images by
        # stamp; the message is what ~/score/camera_info is made from.
        self._infos: StampedBuffer[tuple[CameraIntrinsics, str, CameraInfo]] = StampedBuffer(64)
        self.subscriptions: list[Subscription] = []
        # The image and camera_info subscriptions among them, by input.
        self._camera: dict[str, Subscription] = {}
        self._sun_direction = np.asarray(config.sun_direction, dtype=np.float64)
        self._sun_strength = config.sun_strength
        self._sun_from_topic = False
        self._sun_directions: StampedBuffer[np.ndarray] = StampedBuffer(512)
        self._bodies: tuple = ()
        self.pose_source: PoseSource | None = None

    @property
    def sun_direction(self) -> np.ndarray:
        """The Sun direction in force: the last one received, else the parameter's."""
        return self._sun_direction

    def configure(self, config: NodeConfig) -> None:
        """Use ``config`` from now on; its Sun direction and strength apply only until the
        Sun topics have given theirs."""
        with self._lock:
            self._config = config
            if not self._sun_from_topic:
                self._sun_direction = np.asarray(config.sun_direction, dtype=np.float64)
                self._sun_strength = config.sun_strength

    def open(
        self,
        image_type: type,
        image_topic: str,
        info_topic: str,
        state_qos: QoSProfile,
        diagnostics: Diagnostics,
    ) -> None:
        """Subscribe to the Sun strength and the bodies; :meth:`subscribe` takes the rest.

        Parameters
        ----------
        image_type : type
            ``sensor_msgs/Image`` or, for the compressed transport, ``CompressedImage``.
        image_topic, info_topic : str
            The resolved image topic and its camera_info topic.
        state_qos : QoSProfile
            QoS of the Sun and body topics.
        diagnostics : Diagnostics
            Counts the inputs and their errors.
        """
        self._image_type, self._image_topic, self._info_topic = image_type, image_topic, info_topic
        self._state_qos = state_qos
        self._diagnostics = diagnostics
        self._node.create_subscription(
            Float32, interface.SUN_STRENGTH_INPUT, self.on_sun_strength, state_qos
        )
        self._node.create_subscription(
            MarkerArray, interface.BODIES_INPUT, self.on_bodies, state_qos
        )

    # --- subscribed while an output is ----------------------------------------------------

    def subscribe(self) -> None:
        """Subscribe to the Sun direction, the image, its camera_info and the pose topic."""

        def inputs(depth: int | None = None) -> QoSProfile:
            # A copy each: an override sets the policy on the profile object it is given.
            profile = copy.copy(qos_profile_sensor_data)
            profile.depth = depth or profile.depth
            return profile

        node = self._node
        with self._lock:
            self._first_info_ns = None
        self._camera = {
            "image": node.create_subscription(
                self._image_type,
                self._image_topic,
                # With the message info, where rclpy passes it: when each image was sent.
                message_info_callback(self.on_image),
                inputs(IMAGE_DEPTH),
                qos_overriding_options=self._overriding(),
            ),
            "camera_info": node.create_subscription(
                CameraInfo,
                self._info_topic,
                self.on_camera_info,
                inputs(),
                qos_overriding_options=self._overriding(),
            ),
        }
        self.subscriptions = [
            # The Sun direction is stamped per frame by its publisher; while idle the node
            # keeps the last one it received.
            node.create_subscription(
                Vector3Stamped, interface.SUN_DIRECTION_INPUT, self.on_sun, self._state_qos
            ),
            *self._camera.values(),
        ]
        if self.pose_source is not None:
            self.pose_source.set_active(True)

    def unsubscribe(self) -> None:
        """Drop the subscriptions :meth:`subscribe` made."""
        for subscription in self.subscriptions:
            self._node.destroy_subscription(subscription)
        self.subscriptions = []
        self._camera = {}
        if self.pose_source is not None:
            self.pose_source.set_active(False)

    def update(self) -> None:
        """Subscribe to the image, its camera_info, the pose topic and the Sun direction only
        while an output has a subscriber, as image_pipeline nodes do: else every 6 MB frame
        crosses DDS for nothing."""
        if not self._node.context.ok():
            return  # shutting down: the graph cannot be asked any more
        wanted = self._wanted()
        if wanted and not self.subscriptions:
            self.subscribe()
            self._node.get_logger().info(
                f"an output has a subscriber: subscribed to {self._image_topic} and "
                f"{self._info_topic}"
            )
        elif not wanted and self.subscriptions:
            self.unsubscribe()
            self._node.get_logger().info(
                f"no output has a subscriber: unsubscribed from {self._image_topic} and "
                f"{self._info_topic}"
            )

    def publisher_counts(self) -> dict[str, int]:
        """The publishers the image and camera_info subscriptions have matched (0 while
        unsubscribed), as ``/diagnostics`` reports them.

        A camera sees the node's subscription (its publisher's ``get_subscription_count``)
        before the node's side has matched the camera's publisher, and DDS drops what a
        best-effort subscription receives from a publisher it has not matched: only once these
        counts are up is an image sure to arrive (the node is ready for it).
        """
        counts = {"image": 0, "camera_info": 0}
        for name, subscription in self._camera.items():
            counts[name] = matched_publishers(self._node, subscription)
        return counts

    def idle_reason(self) -> str:
        """Why no frame is processed on purpose ("" when an output is subscribed)."""
        if not self._node.context.ok():
            return "shutting down"
        if self._wanted():
            return ""
        if self.subscriptions:
            return "no subscriber to any output: unsubscribing the inputs"
        return "no subscriber to any output: inputs unsubscribed"

    # --- callbacks ------------------------------------------------------------------------

    def on_image(self, msg: Image | CompressedImage, info: Mapping[str, int] | None = None) -> None:
        """Keep the image for the processing threads; none is kept while no output has a
        subscriber. ``info``: rclpy's message info, whose source and reception timestamps
        say when the image was published and when the middleware received it."""
        received = time.monotonic()
        stamp_ns = messages.stamp_to_ns(msg.header.stamp)
        self._diagnostics.input_seen(
            msg.header.frame_id, stamp_ns, self._node.get_clock().now().nanoseconds
        )
        if not self._wanted():
            # Nobody listens: neither render nor detect.
            self._diagnostics.count("frames_skipped_no_subscribers")
            return
        if self.images.put(arrival_of(msg, received, info, time.time_ns())):
            self._diagnostics.count("frames_dropped_stale")

    def on_camera_info(self, msg: CameraInfo) -> None:
        """Keep a valid camera_info by its stamp (an invalid one is reported)."""
        try:
            intrinsics = messages.check_camera_size(
                messages.camera_intrinsics(msg, self._config.rectified_input)
            )
        except MessageError as error:
            self._diagnostics.report(error)
            return
        self._infos.add(
            messages.stamp_to_ns(msg.header.stamp), (intrinsics, msg.header.frame_id, msg)
        )
        with self._lock:
            self._intrinsics = intrinsics
            if self._first_info_ns is None:
                self._first_info_ns = messages.stamp_to_ns(msg.header.stamp)

    def on_sun(self, msg: Vector3Stamped) -> None:
        """Keep the Sun direction, in the station frame, by its stamp."""
        try:
            direction = messages.vector_to_direction(msg.vector)
            direction = self.pose_source.in_station(msg.header, direction, "sun")
        except MessageError as error:
            self._diagnostics.report(error)
            return
        self._sun_directions.add(messages.stamp_to_ns(msg.header.stamp), direction)
        with self._lock:
            self._sun_direction, self._sun_from_topic = direction, True

    def on_sun_strength(self, msg: Float32) -> None:
        """Keep the Sun strength (a negative or non-finite one is reported)."""
        if not np.isfinite(msg.data) or msg.data < 0:
            self._diagnostics.report(
                MessageError("sun", f"sun strength {msg.data} must be finite and >= 0")
            )
            return
        with self._lock:
            self._sun_strength, self._sun_from_topic = float(msg.data), True

    def on_bodies(self, msg: MarkerArray) -> None:
        """Keep the celestial bodies, centred in the station frame."""
        try:
            bodies = tuple(messages.markers_to_bodies(msg.markers))
            bodies = self.pose_source.bodies_in_station(msg.markers, bodies)
        except MessageError as error:
            self._diagnostics.report(error)
            return
        with self._lock:
            self._bodies = bodies

    # --- what the processing threads ask for ----------------------------------------------

    def snapshot(self, msg: Image | CompressedImage | None = None) -> Snapshot:
        """The node state for ``msg`` (its camera_info paired by stamp), or for building the
        renderer ahead of the first frame (``msg`` None: the latest camera_info)."""
        problem = None
        intrinsics = None
        if msg is not None:
            intrinsics, problem = self._camera_for(msg)
        with self._lock:
            return Snapshot(
                self._intrinsics if msg is None else intrinsics,
                self._config,
                self._sun_direction,
                self._sun_strength,
                self._bodies,
                problem,
                waiting_for_camera_info=problem is not None and self._before_camera_info(msg),
            )

    def _before_camera_info(self, msg: Image | CompressedImage | None) -> bool:
        """Whether ``msg`` came before the camera_info stream since (re)subscribing: none
        received yet, or the first one stamped after the image (called with the lock)."""
        if self._first_info_ns is None:
            return True
        return msg is not None and messages.stamp_to_ns(msg.header.stamp) < self._first_info_ns

    def size_refusal(self, msg: Image | CompressedImage) -> MessageError | None:
        """Why ``msg`` would be refused for its size, told without waiting or decoding: a
        raw image's width and height against the camera_info of its stamp (the latest
        where none is paired yet). None when it fits or cannot be told yet (a compressed
        image says its size only once decoded; no camera_info received)."""
        if not isinstance(msg, Image):
            return None
        entry = self._infos.nearest(
            messages.stamp_to_ns(msg.header.stamp),
            round(self._config.camera_info_tolerance_s * 1e9),
        )
        with self._lock:
            intrinsics = self._intrinsics if entry is None else entry[0]
        if intrinsics is None:
            return None
        try:
            messages.check_size(msg.width, msg.height, (intrinsics.width, intrinsics.height))
        except MessageError as error:
            return error
        return None

    def camera_info_of(self, msg: Image | CompressedImage) -> CameraInfo | None:
        """The camera_info message paired with ``msg`` by stamp, as :meth:`snapshot` pairs
        them, without waiting (None when none is within ``camera_info_tolerance_s``)."""
        entry = self._infos.nearest(
            messages.stamp_to_ns(msg.header.stamp),
            round(self._config.camera_info_tolerance_s * 1e9),
        )
        return None if entry is None else entry[2]

    def _camera_for(
        self, msg: Image | CompressedImage
    ) -> tuple[CameraIntrinsics | None, MessageError | None]:
        """The camera_info of the image's stamp (exact, or nearest within
        ``camera_info_tolerance_s``), as image_transport's CameraSubscriber pairs them;
        waits up to :data:`CAMERA_INFO_WAIT_S` for it. A differing frame_id is counted."""
        stamp_ns = messages.stamp_to_ns(msg.header.stamp)
        tolerance_s = self._config.camera_info_tolerance_s
        tolerance_ns = round(tolerance_s * 1e9)
        deadline = time.monotonic() + CAMERA_INFO_WAIT_S
        entry = self._infos.nearest(stamp_ns, tolerance_ns)
        while entry is None and time.monotonic() < deadline:
            time.sleep(0.002)
            entry = self._infos.nearest(stamp_ns, tolerance_ns)
        if entry is None:
            return None, MessageError(
                "camera_info",
                f"no valid camera_info on {self._info_topic} stamped within {tolerance_s} s of "
                f"image stamp {stamp_ns} ns (camera_info_tolerance_s); frame skipped",
            )
        intrinsics, info_frame, _ = entry
        image_frame = str(msg.header.frame_id)
        if info_frame != image_frame:
            self._diagnostics.count("camera_info_frame_mismatches")
            self._node.get_logger().warning(
                f"camera_info frame_id {info_frame!r} differs from the image's {image_frame!r} "
                "(counted in /diagnostics as camera_info_frame_mismatches)",
                throttle_duration_sec=10.0,
            )
        return intrinsics, None

    def view_of(self, msg: Image | CompressedImage, state: Snapshot) -> View | None:
        """Pose and lighting at the image stamp (None, counted, when no pose is known)."""
        tolerance_s = state.config.pose_tolerance_s
        pose = self.pose_source.lookup(msg.header, tolerance_s, state.config.tf_timeout_s)
        if pose is None:
            self._diagnostics.count("pose_lookup_failures")
            self._node.get_logger().warning(
                f"no camera pose within {tolerance_s} s (tf: {state.config.tf_timeout_s} s "
                "wait) of image stamp "
                f"{messages.stamp_to_ns(msg.header.stamp)} ns "
                f"(pose source {self.pose_source.kind}); frame skipped",
                throttle_duration_sec=5.0,
            )
            return None
        # The Sun direction stamped nearest the image, else the latest known one.
        stamped = self._sun_directions.nearest(
            messages.stamp_to_ns(msg.header.stamp), int(tolerance_s * 1e9)
        )
        sun = state.sun_direction if stamped is None else stamped
        return View(pose, sun, state.sun_strength, state.bodies)


def matched_publishers(node: Node, subscription: Subscription) -> int:
    """The publishers ``subscription`` has matched (rclpy of Iron on); Humble's rclpy has no
    such count, so there it is the topic's publishers in the graph, which may come first."""
    count = getattr(subscription, "get_publisher_count", None)
    if count is not None:
        return count()
    return node.count_publishers(subscription.topic_name)


def arrival_of(
    msg: Image | CompressedImage, received: float, info: Mapping[str, int] | None, now_ns: int
) -> Arrival:
    """The image with its instants on the monotonic clock: the callback's (``received``) and,
    from rclpy's message info, its publication and reception by the middleware.

    The middleware's timestamps are on the system clock (the source timestamp on the
    publisher's host's, so hosts' clocks must agree, as TF needs them to); ``now_ns`` is
    this host's system clock at ``received``. A timestamp of 0 is unknown (None); one after
    ``now_ns`` (a publisher's clock ahead of this host's) counts as ``received``.
    """

    def instant(key: str) -> float | None:
        stamp = 0 if info is None else int(info.get(key) or 0)
        return None if stamp <= 0 else received - max(0, now_ns - stamp) / 1e9

    return Arrival(msg, received, instant("source_timestamp"), instant("received_timestamp"))
