"""The ``mrad_detector`` node: camera image and pose in, anomaly score, mask and flag out.

Structure (one place per concern):

* parameters are declared up front (:mod:`.parameters`) and validated at start and on every
  change; a rejected change keeps the old value and says why;
* subscription callbacks only store the newest message (:class:`.buffers.LatestSlot` for
  images, :class:`.buffers.StampedBuffer` for poses), so inputs never wait for processing;
* one processing thread owns the OpenGL renderer (GL contexts are bound to a thread), looks
  up the pose at the image stamp, runs :class:`~allo_mrad_ros.processing.FrameProcessor`
  and publishes with the input image's header;
* a timer publishes ``/diagnostics``.

Outputs: ``~/score`` (32FC1, 0..255) is the continuous pixel ranking map, the cross score
softly saturated (``mrad.pixel_score: continuous``; ``regions`` gives the paper's sparse map,
zero outside the grown regions); ``~/mask`` (mono8 0/255) is the union of the grown regions
and ``~/anomaly`` the image decision on its area.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import Counter
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, Vector3Stamped
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Bool, Float32
from visualization_msgs.msg import MarkerArray

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector import MradParams
from allo_mrad_ros.processing import FrameProcessor
from allo_mrad_ros.render import ReferenceRenderer, RendererError
from allo_mrad_ros.ros import messages
from allo_mrad_ros.ros.buffers import LatestSlot, StageStatistics, StampedBuffer
from allo_mrad_ros.ros.messages import MessageError
from allo_mrad_ros.ros.parameters import (
    NodeParameter,
    detector_parameters,
    detector_params_from,
    node_parameters,
    validate,
)
from allo_mrad_ros.visualise import outline

NODE_NAME = "mrad_detector"

# Input topics: the bag writer's defaults, so a played bag needs no remapping.
IMAGE_TOPIC = "/arm_camera/image_raw"
CAMERA_INFO_TOPIC = "/arm_camera/camera_info"
POSE_TOPIC = "/arm_camera/pose"
SUN_DIRECTION_TOPIC = "/allo/sun_direction"
SUN_STRENGTH_TOPIC = "/allo/sun_strength"
BODIES_TOPIC = "/allo/celestial_bodies"

OVERLAY_COLOUR = (255, 40, 40)


def _tf2_available() -> bool:
    try:
        import tf2_ros  # noqa: F401
    except ImportError:
        return False
    return True


def _descriptor(name: str, parameter: NodeParameter) -> ParameterDescriptor:
    spec = parameter.spec
    descriptor = ParameterDescriptor(description=spec.description, read_only=parameter.read_only)
    if spec.choices and spec.kind is not bool:
        descriptor.additional_constraints = f"one of {list(spec.choices)}"
    elif spec.kind is int and spec.low is not None:
        descriptor.integer_range = [
            IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=1)
        ]
    elif spec.kind is float and spec.low is not None:
        descriptor.floating_point_range = [
            FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high), step=0.0)
        ]
        if spec.low_open or spec.high_open:
            descriptor.additional_constraints = f"{name} in {spec.interval()}"
    return descriptor


class MradDetectorNode(Node):
    """ROS 2 node running MRAD on the arm camera stream."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._tf_available = _tf2_available()
        self._declared = {**node_parameters(self._tf_available), **detector_parameters()}
        values = self._declare_all()
        self._detector_params: MradParams = detector_params_from(values)
        self._settings = values
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._image_slot: LatestSlot[tuple[Image, float]] = LatestSlot()
        self._poses: StampedBuffer[np.ndarray] = StampedBuffer(512)
        self._intrinsics: CameraIntrinsics | None = None
        self._sun_direction = np.asarray(values["sun_direction"], dtype=np.float64)
        self._sun_strength = float(values["sun_strength"])
        self._sun_from_topic = False
        self._sun_directions: StampedBuffer[np.ndarray] = StampedBuffer(512)
        self._bodies: list = []
        self._counters: Counter[str] = Counter()
        self._logged_causes: set[str] = set()
        self._stats = StageStatistics()
        self._lock = threading.Lock()

        self._setup_pose_source(values)
        self._setup_io()
        self._running = True
        self._worker = threading.Thread(target=self._process_loop, name="mrad_processing")
        self._worker.start()
        self.create_timer(values["diagnostics_period_s"], self._publish_diagnostics)
        self.get_logger().info(
            f"MRAD detector ready: pose from {self._pose_source}, reference scale "
            f"{values['reference_scale']}, grid {self._detector_params.grid}, "
            f"listening on {IMAGE_TOPIC}"
        )

    # --- parameters ---------------------------------------------------------------------

    def _declare_all(self) -> dict[str, Any]:
        values = {}
        for name, parameter in self._declared.items():
            value = self.declare_parameter(
                name, parameter.default, _descriptor(name, parameter)
            ).value
            try:
                values[name] = validate(name, parameter, value)
            except ValueError as error:
                # A bad value in the config file: start with the default, say so loudly.
                self.get_logger().error(f"parameter {error}; using default {parameter.default!r}")
                values[name] = parameter.default
        try:
            detector_params_from(values)
        except ValueError as error:
            self.get_logger().error(f"detector parameters rejected ({error}); using defaults")
            for name, parameter in self._declared.items():
                if name.startswith("mrad."):
                    values[name] = parameter.default
        return values

    def _on_set_parameters(self, parameters: list) -> SetParametersResult:
        proposed = dict(self._settings)
        try:
            for parameter in parameters:
                if parameter.name not in self._declared:
                    continue
                proposed[parameter.name] = validate(
                    parameter.name, self._declared[parameter.name], parameter.value
                )
            detector = detector_params_from(proposed)
        except ValueError as error:
            self.get_logger().warning(f"rejected parameter change: {error}")
            return SetParametersResult(successful=False, reason=str(error))
        with self._lock:
            self._settings = proposed
            self._detector_params = detector
            if not self._sun_from_topic:
                self._sun_direction = np.asarray(proposed["sun_direction"], dtype=np.float64)
                self._sun_strength = float(proposed["sun_strength"])
        return SetParametersResult(successful=True)

    # --- inputs -------------------------------------------------------------------------

    def _setup_pose_source(self, values: dict[str, Any]) -> None:
        self._pose_source = values["pose_source"]
        self._tf_buffer = None
        if self._pose_source == "tf" and not self._tf_available:
            self.get_logger().error(
                "pose_source is 'tf' but tf2_ros is not installed (pip install without a ROS "
                f"distro); using pose_source 'topic' on {POSE_TOPIC} instead"
            )
            self._pose_source = "topic"
        if self._pose_source == "tf":
            import tf2_ros

            self._tf_buffer = tf2_ros.Buffer()
            self._tf_listener = tf2_ros.TransformListener(self._tf_buffer, self)
        elif not self._tf_available:
            self.get_logger().info(
                f"tf2_ros is not installed: camera poses come from {POSE_TOPIC} "
                "(geometry_msgs/PoseStamped, pose_source 'topic')"
            )

    def _setup_io(self) -> None:
        inputs = qos_profile_sensor_data
        state = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.create_subscription(Image, IMAGE_TOPIC, self._on_image, inputs)
        self.create_subscription(CameraInfo, CAMERA_INFO_TOPIC, self._on_camera_info, inputs)
        if self._pose_source == "topic":
            self.create_subscription(PoseStamped, POSE_TOPIC, self._on_pose, state)
        self.create_subscription(Vector3Stamped, SUN_DIRECTION_TOPIC, self._on_sun, state)
        self.create_subscription(Float32, SUN_STRENGTH_TOPIC, self._on_sun_strength, state)
        self.create_subscription(MarkerArray, BODIES_TOPIC, self._on_bodies, state)
        # Continuous ranking map (mrad.pixel_score); the mask comes from the grown regions.
        self._pub_score = self.create_publisher(Image, "~/score", 5)
        self._pub_mask = self.create_publisher(Image, "~/mask", 5)
        self._pub_anomaly = self.create_publisher(Bool, "~/anomaly", 10)
        self._pub_reference = self.create_publisher(Image, "~/reference", 5)
        self._pub_overlay = self.create_publisher(Image, "~/overlay", 5)
        self._pub_diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)

    def _on_image(self, msg: Image) -> None:
        if self._image_slot.put((msg, time.monotonic())):
            self._count("frames_dropped_stale")

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            intrinsics = messages.intrinsics_from_camera_info(msg)
        except MessageError as error:
            self._report(error)
            return
        with self._lock:
            self._intrinsics = intrinsics

    def _on_pose(self, msg: PoseStamped) -> None:
        try:
            self._poses.add(
                messages.stamp_to_ns(msg.header.stamp), messages.pose_to_matrix(msg.pose)
            )
        except MessageError as error:
            self._report(error)

    def _on_sun(self, msg: Vector3Stamped) -> None:
        try:
            direction = messages.vector_to_direction(msg.vector)
        except MessageError as error:
            self._report(error)
            return
        self._sun_directions.add(messages.stamp_to_ns(msg.header.stamp), direction)
        with self._lock:
            self._sun_direction, self._sun_from_topic = direction, True

    def _on_sun_strength(self, msg: Float32) -> None:
        if not np.isfinite(msg.data) or msg.data < 0:
            self._report(MessageError("sun", f"sun strength {msg.data} must be finite and >= 0"))
            return
        with self._lock:
            self._sun_strength, self._sun_from_topic = float(msg.data), True

    def _on_bodies(self, msg: MarkerArray) -> None:
        try:
            bodies = messages.markers_to_bodies(msg.markers)
        except MessageError as error:
            self._report(error)
            return
        with self._lock:
            self._bodies = bodies

    # --- processing ---------------------------------------------------------------------

    def _process_loop(self) -> None:
        processor: FrameProcessor | None = None
        built_for: CameraIntrinsics | None = None
        while self._running:
            item = self._image_slot.take(timeout=0.2)
            with self._lock:
                intrinsics, params = self._intrinsics, self._detector_params
                sun, strength, bodies = self._sun_direction, self._sun_strength, list(self._bodies)
            if intrinsics is not None and (processor is None or built_for != intrinsics):
                # Build (or rebuild) as soon as camera_info is known, not when a frame waits.
                try:
                    processor = self._build_processor(intrinsics, params)
                    built_for = intrinsics
                except RendererError as error:
                    self._report(MessageError("renderer", f"cannot build the renderer: {error}"))
                    processor = None
                    continue
            if item is None:
                continue
            msg, received = item
            if processor is None:
                self._report(
                    MessageError(
                        "camera_info", f"no camera_info on {CAMERA_INFO_TOPIC} yet; frame skipped"
                    )
                )
                continue
            try:
                processor.params = params
                image = messages.image_to_rgb(msg, (built_for.width, built_for.height))
                pose = self._lookup_pose(msg)
                if pose is None:
                    continue
                sun = self._sun_at(msg, sun)
                frame = processor.process(image, pose, sun, strength, bodies)
            except MessageError as error:
                self._report(error)
                continue
            except RendererError as error:
                self._report(MessageError("renderer", f"reference rendering failed: {error}"))
                continue
            except ValueError as error:
                self._report(MessageError("processing", f"frame rejected: {error}"))
                continue
            self._publish(msg, image, frame)
            latency = {
                "render": frame.timings_ms["render"],
                "detect": frame.timings_ms["MRAD"],
                "receive_to_publish": 1e3 * (time.monotonic() - received),
            }
            self._stats.record(latency)
            self._count("frames_processed")
            if frame.primary.anomalous:
                self._count("anomalous_frames")

    def _build_processor(self, intrinsics: CameraIntrinsics, params: MradParams) -> FrameProcessor:
        settings = self._settings
        renderer = ReferenceRenderer(
            settings["mesh"] or None,
            intrinsics,
            scale=settings["reference_scale"],
            backend=settings["render_backend"] or None,
            shadows=settings["shadows"],
        )
        self.get_logger().info(
            f"renderer ready: {renderer.backend}, {renderer.triangle_count} triangles, reference "
            f"{renderer.output_intrinsics.width}x{renderer.output_intrinsics.height}"
        )
        return FrameProcessor(renderer, params)

    def _sun_at(self, msg: Image, latest: np.ndarray) -> np.ndarray:
        """The sun direction stamped nearest the image, else the latest known one."""
        tolerance_ns = int(float(self._settings["pose_tolerance_s"]) * 1e9)
        stamped = self._sun_directions.nearest(messages.stamp_to_ns(msg.header.stamp), tolerance_ns)
        return latest if stamped is None else stamped

    def _lookup_pose(self, msg: Image) -> np.ndarray | None:
        stamp_ns = messages.stamp_to_ns(msg.header.stamp)
        tolerance_s = float(self._settings["pose_tolerance_s"])
        if self._tf_buffer is not None:
            pose = self._lookup_tf(msg, tolerance_s)
        else:
            # Topics arrive in no guaranteed order: give the pose of this stamp a moment,
            # as tf2's lookup with a timeout does.
            deadline = time.monotonic() + tolerance_s
            pose = self._poses.nearest(stamp_ns, int(tolerance_s * 1e9))
            while pose is None and time.monotonic() < deadline:
                time.sleep(0.002)
                pose = self._poses.nearest(stamp_ns, int(tolerance_s * 1e9))
        if pose is None:
            self._count("pose_lookup_failures")
            self.get_logger().warning(
                f"no camera pose within {tolerance_s} s of image stamp {stamp_ns} ns "
                f"(pose source {self._pose_source}); frame skipped",
                throttle_duration_sec=5.0,
            )
        return pose

    def _lookup_tf(self, msg: Image, timeout_s: float) -> np.ndarray | None:
        import tf2_ros
        from rclpy.duration import Duration
        from rclpy.time import Time

        camera_frame = self._settings["camera_frame"] or msg.header.frame_id
        try:
            transform = self._tf_buffer.lookup_transform(
                self._settings["station_frame"],
                camera_frame,
                Time.from_msg(msg.header.stamp),
                timeout=Duration(seconds=timeout_s),
            )
        except (
            tf2_ros.LookupException,
            tf2_ros.ConnectivityException,
            tf2_ros.ExtrapolationException,
        ) as error:
            self.get_logger().debug(f"TF lookup failed: {error}")
            return None
        return messages.transform_to_matrix(transform.transform)

    def _publish(self, msg: Image, image: np.ndarray, frame: Any) -> None:
        result = frame.primary
        header = msg.header
        self._pub_score.publish(messages.fill_image(Image(), header, result.score, "32FC1"))
        self._pub_mask.publish(messages.fill_image(Image(), header, result.mask, "mono8"))
        self._pub_anomaly.publish(Bool(data=bool(result.anomalous)))
        if self._settings["publish_reference"]:
            self._pub_reference.publish(
                messages.fill_image(Image(), header, frame.reference, "rgb8")
            )
        if self._settings["publish_overlay"]:
            overlay = outline(_as_uint8(image), result.mask, OVERLAY_COLOUR)
            self._pub_overlay.publish(messages.fill_image(Image(), header, overlay, "rgb8"))

    # --- diagnostics --------------------------------------------------------------------

    def _count(self, name: str) -> None:
        with self._lock:
            self._counters[name] += 1

    def _report(self, error: MessageError) -> None:
        """Count an input error; log it once per cause so a bad stream cannot flood the log."""
        self._count(f"errors_{error.cause}")
        if error.cause not in self._logged_causes:
            self._logged_causes.add(error.cause)
            self.get_logger().error(
                f"{error} (further '{error.cause}' errors are counted in /diagnostics)"
            )

    def _publish_diagnostics(self) -> None:
        with self._lock:
            counters = dict(self._counters)
        counters["frames_received"] = self._image_slot.received
        status = DiagnosticStatus(name=f"{self.get_name()}: pipeline", hardware_id="arm_camera")
        values = {"rate_hz": f"{self._stats.rate_hz():.2f}", "pose_source": self._pose_source}
        for stage, (p50, p95) in self._stats.percentiles().items():
            values[f"latency_{stage}_ms_p50"] = f"{p50:.1f}"
            values[f"latency_{stage}_ms_p95"] = f"{p95:.1f}"
        values.update({name: str(count) for name, count in sorted(counters.items())})
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        problems = [k for k in counters if k.startswith("errors_") or k == "pose_lookup_failures"]
        if problems:
            status.level = DiagnosticStatus.WARN
            status.message = "input problems: " + ", ".join(sorted(problems))
        elif counters.get("frames_processed", 0) == 0:
            status.level = DiagnosticStatus.WARN
            status.message = "no frames processed yet"
        else:
            status.level = DiagnosticStatus.OK
            status.message = "running"
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._pub_diagnostics.publish(array)

    def destroy_node(self) -> None:
        """Stop the processing thread, then destroy the node."""
        self._running = False
        self._image_slot.close()
        if self._worker.is_alive():
            self._worker.join(timeout=5.0)
        super().destroy_node()


def _as_uint8(image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint8:
        return image
    return (image / 257).astype(np.uint8)


def main(argv: list[str] | None = None) -> int:
    """Run the node until shutdown (``ros2 run allo_mrad_ros mrad_detector``)."""
    rclpy.init(args=argv if argv is not None else sys.argv)
    node = None
    try:
        node = MradDetectorNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
