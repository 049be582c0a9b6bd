"""The ``mrad_detector`` node: camera image and pose in, anomaly score, mask and flag out.

One place per concern:

* parameters are declared up front (:mod:`.parameters`) and validated at start and on every
  change into one immutable :class:`~.parameters.NodeConfig`; a rejected change keeps the
  old value and says why;
* subscription callbacks only store the newest message (:class:`.buffers.LatestSlot` for
  images, :class:`.buffers.StampedBuffer` for poses and Sun directions), so inputs never
  wait for processing;
* :class:`.pose_source.PoseSource` looks the camera pose up (TF or topic);
* :class:`.worker.ProcessingWorker` owns the OpenGL renderer and an immutable
  :class:`~allo_mrad_ros.pipeline.Pipeline`, swapped on a parameter change;
* :class:`.diagnostics.Diagnostics` counts and publishes ``/diagnostics``.

Topic names come from :mod:`allo_mrad_ros.interface`.
"""

from __future__ import annotations

import sys
import threading
import time
from typing import Any

import numpy as np
import rclpy
from geometry_msgs.msg import Vector3Stamped
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Bool, Float32
from visualization_msgs.msg import MarkerArray

from allo_mrad_ros import interface
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.pipeline import ProcessedFrame
from allo_mrad_ros.ros import messages
from allo_mrad_ros.ros.buffers import LatestSlot, StampedBuffer
from allo_mrad_ros.ros.diagnostics import Diagnostics
from allo_mrad_ros.ros.messages import MessageError
from allo_mrad_ros.ros.parameters import (
    NodeConfig,
    NodeParameter,
    ParameterError,
    command_line_parameters,
    detector_parameters,
    node_config_from,
    node_parameters,
    validate,
)
from allo_mrad_ros.ros.pose_source import PoseSource, tf2_available
from allo_mrad_ros.ros.worker import ProcessingWorker, Snapshot
from allo_mrad_ros.view import View
from allo_mrad_ros.visualise import outline

OVERLAY_COLOUR = (255, 40, 40)
# Exit status when a parameter value is invalid (as for a command-line usage error).
EXIT_INVALID_PARAMETER = 2


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

    def __init__(self, command_line: dict[str, Any] | None = None, **kwargs: Any) -> None:
        super().__init__(interface.NODE_NAME, **kwargs)
        self._command_line = command_line or {}
        self._declared = {**node_parameters(tf2_available()), **detector_parameters()}
        try:
            self._values = self._declare_all()
        except ParameterError:
            super().destroy_node()  # nothing else is built yet
            raise
        self._config: NodeConfig = node_config_from(self._values)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._lock = threading.Lock()
        self._image_slot: LatestSlot[tuple[Image, float]] = LatestSlot()
        self._intrinsics: CameraIntrinsics | None = None
        self._sun_direction = np.asarray(self._config.sun_direction, dtype=np.float64)
        self._sun_strength = self._config.sun_strength
        self._sun_from_topic = False
        self._sun_directions: StampedBuffer[np.ndarray] = StampedBuffer(512)
        self._bodies: tuple = ()

        config = self._config
        self._diagnostics = Diagnostics(
            self,
            config.diagnostics_period_s,
            lambda: self._image_slot.received,
            "",
            config.input_timeout_s,
            config.hardware_id,
        )
        state = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT)
        self._pose_source = PoseSource(
            self,
            config.pose_source,
            config.station_frame,
            config.camera_frame,
            state,
            self._diagnostics.report,
        )
        self._diagnostics.pose_source = self._pose_source.kind
        self._setup_io(state)
        self._worker = ProcessingWorker(
            self._image_slot,
            self._snapshot,
            self._view_of,
            self._publish,
            self._diagnostics,
            self.get_logger(),
        )
        self._diagnostics.worker_alive = self._worker.is_alive
        self.get_logger().info(
            f"MRAD detector ready: pose from {self._pose_source.kind}, reference scale "
            f"{config.pipeline.render.reference_scale}, grid {config.pipeline.params.grid}, "
            f"listening on {interface.IMAGE_TOPIC}"
        )

    # --- parameters ---------------------------------------------------------------------

    def _declare_all(self) -> dict[str, Any]:
        """Declare every parameter; refuse to start on any invalid value (ParameterError).

        rclpy checks types and ranges inside ``declare_parameter``; its exception is replaced
        by the package's own message. An integer given for a float is accepted and
        re-declared as the float in use, so ``ros2 param get`` shows what the node uses.
        """
        values: dict[str, Any] = {}
        problems: list[str] = []
        for name, parameter in self._declared.items():
            descriptor = _descriptor(name, parameter)
            try:
                requested = self.declare_parameter(name, parameter.default, descriptor).value
                declared = True
            except ParameterException:
                override = self._parameter_overrides.get(name)
                requested = None if override is None else override.value
                declared = False
            try:
                values[name] = validate(name, parameter, requested)
            except ValueError as error:
                problems.append(str(error))
            if not declared:
                value = values.get(name, parameter.default)
                self.declare_parameter(name, value, descriptor, ignore_override=True)
        for name, text in self._command_line.items():
            if name in self._declared:
                try:
                    validate(name, self._declared[name], text)
                except ValueError as error:
                    problems.append(str(error))
        if not problems:
            try:
                node_config_from(values)
            except ValueError as error:
                problems.append(str(error))
        if problems:
            raise ParameterError("invalid parameter value: " + "; ".join(dict.fromkeys(problems)))
        return values

    def _on_set_parameters(self, parameters: list) -> SetParametersResult:
        proposed = dict(self._values)
        try:
            for parameter in parameters:
                if parameter.name not in self._declared:
                    continue
                proposed[parameter.name] = validate(
                    parameter.name, self._declared[parameter.name], parameter.value
                )
            config = node_config_from(proposed)
        except ValueError as error:
            self.get_logger().warning(f"rejected parameter change: {error}")
            return SetParametersResult(successful=False, reason=str(error))
        with self._lock:
            self._values, self._config = proposed, config
            if not self._sun_from_topic:
                self._sun_direction = np.asarray(config.sun_direction, dtype=np.float64)
                self._sun_strength = config.sun_strength
        return SetParametersResult(successful=True)

    # --- inputs -------------------------------------------------------------------------

    def _setup_io(self, state: QoSProfile) -> None:
        inputs = qos_profile_sensor_data
        self.create_subscription(Image, interface.IMAGE_TOPIC, self._on_image, inputs)
        self.create_subscription(
            CameraInfo, interface.CAMERA_INFO_TOPIC, self._on_camera_info, inputs
        )
        self.create_subscription(Vector3Stamped, interface.SUN_DIRECTION_TOPIC, self._on_sun, state)
        self.create_subscription(
            Float32, interface.SUN_STRENGTH_TOPIC, self._on_sun_strength, state
        )
        self.create_subscription(MarkerArray, interface.BODIES_TOPIC, self._on_bodies, state)
        self._pub_score = self.create_publisher(Image, interface.SCORE_OUTPUT, 5)
        self._pub_mask = self.create_publisher(Image, interface.MASK_OUTPUT, 5)
        self._pub_anomaly = self.create_publisher(Bool, interface.ANOMALY_OUTPUT, 10)
        self._pub_reference = self.create_publisher(Image, interface.REFERENCE_OUTPUT, 5)
        self._pub_overlay = self.create_publisher(Image, interface.OVERLAY_OUTPUT, 5)

    def _on_image(self, msg: Image) -> None:
        self._diagnostics.input_seen(msg.header.frame_id)
        if self._image_slot.put((msg, time.monotonic())):
            self._diagnostics.count("frames_dropped_stale")

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            intrinsics = messages.check_camera_size(messages.intrinsics_from_camera_info(msg))
        except MessageError as error:
            self._diagnostics.report(error)
            return
        with self._lock:
            self._intrinsics = intrinsics

    def _on_sun(self, msg: Vector3Stamped) -> None:
        try:
            direction = messages.vector_to_direction(msg.vector)
        except MessageError as error:
            self._diagnostics.report(error)
            return
        self._sun_directions.add(messages.stamp_to_ns(msg.header.stamp), direction)
        with self._lock:
            self._sun_direction, self._sun_from_topic = direction, True

    def _on_sun_strength(self, msg: Float32) -> None:
        if not np.isfinite(msg.data) or msg.data < 0:
            self._diagnostics.report(
                MessageError("sun", f"sun strength {msg.data} must be finite and >= 0")
            )
            return
        with self._lock:
            self._sun_strength, self._sun_from_topic = float(msg.data), True

    def _on_bodies(self, msg: MarkerArray) -> None:
        try:
            bodies = tuple(messages.markers_to_bodies(msg.markers))
        except MessageError as error:
            self._diagnostics.report(error)
            return
        with self._lock:
            self._bodies = bodies

    # --- what the worker asks for -------------------------------------------------------

    def _snapshot(self) -> Snapshot:
        with self._lock:
            return Snapshot(
                self._intrinsics,
                self._config,
                self._sun_direction,
                self._sun_strength,
                self._bodies,
            )

    def _view_of(self, msg: Image, state: Snapshot) -> View | None:
        """Pose and lighting at the image stamp (None, counted, when no pose is known)."""
        tolerance_s = state.config.pose_tolerance_s
        pose = self._pose_source.lookup(msg.header, tolerance_s)
        if pose is None:
            self._diagnostics.count("pose_lookup_failures")
            self.get_logger().warning(
                f"no camera pose within {tolerance_s} s of image stamp "
                f"{messages.stamp_to_ns(msg.header.stamp)} ns "
                f"(pose source {self._pose_source.kind}); frame skipped",
                throttle_duration_sec=5.0,
            )
            return None
        # The Sun direction stamped nearest the image, else the latest known one.
        stamped = self._sun_directions.nearest(
            messages.stamp_to_ns(msg.header.stamp), int(tolerance_s * 1e9)
        )
        sun = state.sun_direction if stamped is None else stamped
        return View(pose, sun, state.sun_strength, state.bodies)

    # --- outputs ------------------------------------------------------------------------

    def _publish(self, msg: Image, image: np.ndarray, frame: ProcessedFrame) -> None:
        result = frame.primary
        header = msg.header
        config = self._config
        fill = messages.fill_image
        self._pub_score.publish(fill(Image(), header, result.score, interface.SCORE_ENCODING))
        self._pub_mask.publish(fill(Image(), header, result.mask, interface.MONO8))
        self._pub_anomaly.publish(Bool(data=bool(result.anomalous)))
        if config.publish_reference:
            self._pub_reference.publish(fill(Image(), header, frame.reference, interface.RGB8))
        if config.publish_overlay:
            overlay = outline(_as_uint8(image), result.mask, OVERLAY_COLOUR)
            self._pub_overlay.publish(fill(Image(), header, overlay, interface.RGB8))

    def destroy_node(self) -> None:
        """Stop the processing thread (nothing is published after), then destroy the node."""
        worker = getattr(self, "_worker", None)
        if worker is not None:
            worker.stop()
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
        node = MradDetectorNode(command_line_parameters(argv if argv is not None else sys.argv))
        rclpy.spin(node)
    except ParameterError as error:
        print(f"{interface.NODE_NAME}: {error}", file=sys.stderr)
        return EXIT_INVALID_PARAMETER
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
