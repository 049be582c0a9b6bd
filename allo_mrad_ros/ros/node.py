"""The ``mrad_detector`` node: camera image and pose in, anomaly score, mask and flag out.

One place per concern:

* parameters are declared up front (:mod:`.parameters`) and validated at start and on every
  change into one immutable :class:`~.parameters.NodeConfig`; a rejected change keeps the
  old value and says why;
* subscription callbacks only store the newest message (:class:`.buffers.LatestSlot` for
  images, :class:`.buffers.StampedBuffer` for poses and Sun directions), so inputs never
  wait for processing;
* :class:`.pose_source.PoseSource` looks the camera pose up (TF or topic);
* :class:`.worker.ProcessingWorker` renders (its render thread owns OpenGL) frame n+1 while
  its detect thread detects and publishes frame n with an immutable, swappable ``Pipeline``;
* :class:`.diagnostics.Diagnostics` counts and publishes ``/diagnostics``.

Topic names come from :mod:`allo_mrad_ros.interface`.

Outputs: ``~/score`` (32FC1, 0..255) is the continuous pixel ranking map, the cross score
softly saturated (``mrad.pixel_score: continuous``; ``regions`` gives the paper's sparse map,
zero outside the grown regions); ``~/mask`` (mono8 0/255) is the union of the grown regions
and ``~/anomaly`` the image decision on its area.
"""

from __future__ import annotations

import copy
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
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Float32
from visualization_msgs.msg import MarkerArray

from allo_mrad_ros import interface
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.pipeline import ProcessedFrame
from allo_mrad_ros.ros import messages, process_tuning
from allo_mrad_ros.ros.buffers import LatestSlot, StampedBuffer
from allo_mrad_ros.ros.diagnostics import Diagnostics
from allo_mrad_ros.ros.messages import MessageError
from allo_mrad_ros.ros.outputs import Outputs
from allo_mrad_ros.ros.parameters import (
    NodeParameter,
    ParameterError,
    check_params_files,
    command_line_parameters,
    detector_parameters,
    node_config_from,
    node_parameters,
    unknown_parameters,
    validate,
)
from allo_mrad_ros.ros.pose_source import PoseSource, tf2_available
from allo_mrad_ros.ros.worker import ProcessingWorker, Snapshot
from allo_mrad_ros.view import View

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
        config = self._config = node_config_from(self._values)
        tuning = process_tuning.apply(config.keep_freed_memory_mb, config.opencv_threads)
        self.get_logger().info(tuning)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._lock = threading.Lock()
        self._image_slot: LatestSlot[tuple[Image, float]] = LatestSlot()
        self._intrinsics: CameraIntrinsics | None = None
        self._sun_direction = np.asarray(self._config.sun_direction, dtype=np.float64)
        self._sun_strength = self._config.sun_strength
        self._sun_from_topic = False
        self._sun_directions: StampedBuffer[np.ndarray] = StampedBuffer(512)
        self._bodies: tuple = ()

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
            config.pipelined,
            lambda: self._outputs.score.get_subscription_count() > 0,
        )
        self._diagnostics.worker_alive = self._worker.is_alive
        self.get_logger().info(
            f"MRAD detector ready: pose from {self._pose_source.kind}, reference scale "
            f"{config.pipeline.render.reference_scale}, grid {config.pipeline.params.grid}, "
            f"{'pipelined' if config.pipelined else 'serial'} processing, "
            f"listening on {self._image_topic}"
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
        # A misspelt parameter would otherwise be ignored without a word (rclpy's rule).
        given = {*self._parameter_overrides, *self._command_line}
        for warning in unknown_parameters(given, self._declared):
            self.get_logger().warning(warning)
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
        # Relative names: they resolve in the node's namespace; QoS overridable at start
        # (qos_overrides.<resolved topic>.subscription.<policy>, read-only parameters).
        overrides = QoSOverridingOptions.with_default_policies()

        def inputs() -> QoSProfile:
            # A copy each: an override sets the policy on the profile object it is given.
            return copy.copy(qos_profile_sensor_data)

        image_type, image_topic = Image, interface.IMAGE_INPUT
        if self._config.image_transport == "compressed":
            # image_transport's rule: the remapped, resolved base topic + "/compressed".
            image_topic = self.resolve_topic_name(image_topic) + interface.COMPRESSED_SUFFIX
            image_type = CompressedImage
        self._image_topic = self.resolve_topic_name(image_topic)
        self.create_subscription(
            image_type, image_topic, self._on_image, inputs(), qos_overriding_options=overrides
        )
        info_topic, on_info = interface.CAMERA_INFO_INPUT, self._on_camera_info
        self.create_subscription(
            CameraInfo, info_topic, on_info, inputs(), qos_overriding_options=overrides
        )
        self.create_subscription(Vector3Stamped, interface.SUN_DIRECTION_INPUT, self._on_sun, state)
        self.create_subscription(
            Float32, interface.SUN_STRENGTH_INPUT, self._on_sun_strength, state
        )
        self.create_subscription(MarkerArray, interface.BODIES_INPUT, self._on_bodies, state)
        self._outputs = Outputs(self)

    def _on_image(self, msg: Image | CompressedImage) -> None:
        self._diagnostics.input_seen(msg.header.frame_id)
        config = self._config
        if not self._outputs.wanted(config.publish_reference, config.publish_overlay):
            # Nobody listens: neither render nor detect.
            self._diagnostics.count("frames_skipped_no_subscribers")
            return
        if self._image_slot.put((msg, time.monotonic())):
            self._diagnostics.count("frames_dropped_stale")

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            intrinsics = messages.check_camera_size(
                messages.camera_intrinsics(msg, self._config.rectified_input)
            )
        except MessageError as error:
            self._diagnostics.report(error)
            return
        with self._lock:
            self._intrinsics = intrinsics

    def _on_sun(self, msg: Vector3Stamped) -> None:
        try:
            direction = messages.vector_to_direction(msg.vector)
            direction = self._pose_source.in_station(msg.header, direction, "sun")
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
            bodies = self._pose_source.bodies_in_station(msg.markers, bodies)
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
        pose = self._pose_source.lookup(msg.header, tolerance_s, state.config.tf_timeout_s)
        if pose is None:
            self._diagnostics.count("pose_lookup_failures")
            self.get_logger().warning(
                f"no camera pose within {tolerance_s} s (tf: {state.config.tf_timeout_s} s "
                "wait) of image stamp "
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

    def _publish(
        self, msg: Image, image: np.ndarray, frame: ProcessedFrame, score_map: bool = True
    ) -> None:
        config = self._config
        with self._lock:
            camera = self._intrinsics
        reference_camera = None
        if camera is not None:
            reference_camera = camera.scaled(config.pipeline.render.reference_scale)
            if (reference_camera.height, reference_camera.width) != frame.reference.shape[:2]:
                reference_camera = None  # camera_info changed under this frame
        self._outputs.publish(
            msg.header,
            image,
            frame,
            reference_camera,
            config.publish_reference,
            config.publish_overlay,
            score_map,
        )

    def destroy_node(self) -> None:
        """Stop the processing thread (nothing is published after), then destroy the node."""
        worker = getattr(self, "_worker", None)
        if worker is not None:
            worker.stop()
        super().destroy_node()


def main(argv: list[str] | None = None) -> int:
    """Run the node until shutdown (``ros2 run allo_mrad_ros mrad_detector``)."""
    arguments = argv if argv is not None else sys.argv
    try:
        check_params_files(arguments)
    except ParameterError as error:
        print(f"{interface.NODE_NAME}: {error}", file=sys.stderr)
        return EXIT_INVALID_PARAMETER
    rclpy.init(args=arguments)
    node = None
    try:
        node = MradDetectorNode(command_line_parameters(arguments))
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
