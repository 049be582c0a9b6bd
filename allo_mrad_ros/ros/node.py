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
zero outside the grown regions), at the detector's processing resolution with
``~/score/camera_info`` (``score_full_resolution``: at the image's); ``~/mask`` (mono8 0/255)
is the union of the grown regions and ``~/anomaly`` the image decision on its area.
"""

from __future__ import annotations

import copy
import sys
import threading
import time
from pathlib import Path
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
from rclpy.qos import QoSPolicyKind, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.subscription import Subscription
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
    check_command_line,
    check_mesh,
    check_params_files,
    command_line_parameters,
    detector_parameters,
    keys_for_other_nodes,
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
# Every QoS policy a publisher or subscription can be given is overridable
# (qos_overrides.<topic>.<publisher|subscription>.<policy>); rclpy's default set has three.
QOS_POLICIES = tuple(
    kind
    for kind in QoSPolicyKind
    if kind not in (QoSPolicyKind.INVALID, QoSPolicyKind.AVOID_ROS_NAMESPACE_CONVENTIONS)
)
# How often the node looks whether any output has a subscriber (to subscribe to its inputs).
INPUT_POLL_S = 0.25
# Longest wait of the processing thread for the camera_info of an image's stamp: the two
# topics arrive in no guaranteed order.
CAMERA_INFO_WAIT_S = 0.5


def qos_overriding() -> QoSOverridingOptions:
    """Overrides of every QoS policy (rclpy's ``with_default_policies`` has three)."""
    return QoSOverridingOptions(policy_kinds=QOS_POLICIES)


def camera_info_topic(image_topic: str) -> str:
    """image_transport's ``getCameraInfoTopic``: ``camera_info`` beside the image topic."""
    parent = image_topic.rsplit("/", 1)[0]
    return f"{parent}/camera_info"


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

    def __init__(
        self,
        command_line: dict[str, Any] | None = None,
        params_files: dict[Path, list[str]] | None = None,
        managed: bool = False,
        **kwargs: Any,
    ) -> None:
        """Declare and validate the parameters; unless ``managed`` (the lifecycle variant,
        which does the rest on configure and activate), build everything and start.

        Raises
        ------
        ParameterError
            For an invalid parameter, mesh or QoS override (the node is destroyed).
        """
        if not managed:
            super().__init__(interface.NODE_NAME, **kwargs)
        self._managed = managed
        self._command_line = command_line or {}
        self._declared = {**node_parameters(tf2_available()), **detector_parameters()}
        try:
            self._values = self._declare_all()
        except ParameterError:
            super().destroy_node()  # nothing else is built yet
            raise
        for warning in keys_for_other_nodes(params_files or {}, self.get_fully_qualified_name()):
            self.get_logger().warning(warning)
        config = self._config = node_config_from(self._values)
        # Logged once the node is built: a refusal before it is the only line printed.
        self._tuning = process_tuning.apply(config.keep_freed_memory_mb, config.opencv_threads)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._lock = threading.Lock()
        self._image_slot: LatestSlot[tuple[Image, float]] = LatestSlot()
        self._intrinsics: CameraIntrinsics | None = None
        # Valid camera_infos by stamp: (intrinsics, frame_id, message), paired with images by
        # stamp; the message is what ~/score/camera_info is made from.
        self._infos: StampedBuffer[tuple[CameraIntrinsics, str, CameraInfo]] = StampedBuffer(64)
        self._input_subscriptions: list[Subscription] = []
        self._sun_direction = np.asarray(self._config.sun_direction, dtype=np.float64)
        self._sun_strength = self._config.sun_strength
        self._sun_from_topic = False
        self._sun_directions: StampedBuffer[np.ndarray] = StampedBuffer(512)
        self._bodies: tuple = ()
        self._input_timer = None
        self._worker: ProcessingWorker | None = None
        if not managed:
            self._build()
            self._start_inputs()

    def _build(self) -> None:
        """Load the mesh, create the diagnostics, pose source, inputs, outputs and the
        processing threads (whose render thread builds the renderer for the camera_info's
        camera). Raises ParameterError (the node destroyed, unless managed)."""
        config = self._config
        try:
            check_mesh(config.mesh)
        except ParameterError:
            if not self._managed:
                super().destroy_node()
            raise

        self._diagnostics = Diagnostics(
            self,
            config.diagnostics_period_s,
            lambda: self._image_slot.received,
            "",
            config.input_timeout_s,
            config.hardware_id,
            config.expected_rate_hz,
            config.rate_tolerance,
            config.max_stamp_delay_s,
        )
        state = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT)
        self._setup_io(state)
        try:
            self._check_qos_overrides()
        except ParameterError:
            if not self._managed:
                super().destroy_node()
            raise
        self._pose_source = PoseSource(
            self,
            config.pose_source,
            config.station_frame,
            config.camera_frame,
            state,
            self._diagnostics.report,
        )
        self._diagnostics.pose_source = self._pose_source.kind
        self._diagnostics.idle = self._idle_reason
        self._diagnostics.inputs_subscribed = lambda: bool(self._input_subscriptions)
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
        self.get_logger().info(self._tuning)
        self.get_logger().info(
            f"MRAD detector ready: pose from {self._pose_source.kind}, reference scale "
            f"{config.pipeline.render.reference_scale}, grid {config.pipeline.params.grid}, "
            f"{'pipelined' if config.pipelined else 'serial'} processing, "
            f"listening on {self._image_topic}"
        )

    def _start_inputs(self) -> None:
        """Subscribe to the inputs while an output has a subscriber, from now on."""
        self._update_inputs()  # unsubscribes the inputs while no output is subscribed
        self._input_timer = self.create_timer(INPUT_POLL_S, self._update_inputs)

    def _stop_inputs(self) -> None:
        """Stop watching the outputs and unsubscribe from the image and camera_info."""
        if self._input_timer is not None:
            self.destroy_timer(self._input_timer)
            self._input_timer = None
        self._unsubscribe_inputs()

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
        if values.get("pose_source") == "tf" and not tf2_available():
            problems.append(
                "pose_source is 'tf' but the tf2_ros Python module is not installed (ROS "
                "package tf2_ros_py: apt install ros-$ROS_DISTRO-tf2-ros-py); install it or "
                "set pose_source:=topic"
            )
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
        self._image_type, image_topic = Image, interface.IMAGE_INPUT
        base = self.resolve_topic_name(image_topic)
        if self._config.image_transport == "compressed":
            # image_transport's rule: the remapped, resolved base topic + "/compressed".
            image_topic = base + interface.COMPRESSED_SUFFIX
            self._image_type = CompressedImage
        self._image_topic = self.resolve_topic_name(image_topic)
        # image_transport's CameraSubscriber: camera_info is the sibling of the (remapped)
        # image topic, so remapping the image moves both.
        self._info_topic = camera_info_topic(base)
        self._state_qos = state
        self.create_subscription(
            Float32, interface.SUN_STRENGTH_INPUT, self._on_sun_strength, state
        )
        self.create_subscription(MarkerArray, interface.BODIES_INPUT, self._on_bodies, state)
        self._outputs = Outputs(self, self._config.hardware_id, qos_overriding)
        self._subscribe_inputs()  # once at start: declares the inputs' QoS override parameters

    def _subscribe_inputs(self) -> None:
        def inputs() -> QoSProfile:
            # A copy each: an override sets the policy on the profile object it is given.
            return copy.copy(qos_profile_sensor_data)

        self._input_subscriptions = [
            # The Sun direction is stamped per frame by its publisher; while idle the node
            # keeps the last one it received.
            self.create_subscription(
                Vector3Stamped, interface.SUN_DIRECTION_INPUT, self._on_sun, self._state_qos
            ),
            self.create_subscription(
                self._image_type,
                self._image_topic,
                self._on_image,
                inputs(),
                qos_overriding_options=qos_overriding(),
            ),
            self.create_subscription(
                CameraInfo,
                self._info_topic,
                self._on_camera_info,
                inputs(),
                qos_overriding_options=qos_overriding(),
            ),
        ]
        pose_source = getattr(self, "_pose_source", None)
        if pose_source is not None:
            pose_source.set_active(True)

    def _unsubscribe_inputs(self) -> None:
        for subscription in self._input_subscriptions:
            self.destroy_subscription(subscription)
        self._input_subscriptions = []
        pose_source = getattr(self, "_pose_source", None)
        if pose_source is not None:
            pose_source.set_active(False)

    def _update_inputs(self) -> None:
        """Subscribe to the image, its camera_info, the pose topic and the Sun direction only
        while an output has a subscriber, as image_pipeline nodes do: else every 6 MB frame
        crosses DDS for nothing."""
        if not self.context.ok():
            return  # shutting down: the graph cannot be asked any more
        config = self._config
        wanted = self._outputs.wanted(config.publish_reference, config.publish_overlay)
        if wanted and not self._input_subscriptions:
            self._subscribe_inputs()
            self.get_logger().info(
                f"an output has a subscriber: subscribed to {self._image_topic} and "
                f"{self._info_topic}"
            )
        elif not wanted and self._input_subscriptions:
            self._unsubscribe_inputs()
            self.get_logger().info(
                f"no output has a subscriber: unsubscribed from {self._image_topic} and "
                f"{self._info_topic}"
            )

    def _idle_reason(self) -> str:
        """Why no frame is processed on purpose ("" when an output is subscribed)."""
        if not self.context.ok():
            return "shutting down"
        config = self._config
        if self._outputs.wanted(config.publish_reference, config.publish_overlay):
            return ""
        if self._input_subscriptions:
            return "no subscriber to any output: unsubscribing the inputs"
        return "no subscriber to any output: inputs unsubscribed"

    def _check_qos_overrides(self) -> None:
        """Refuse a ``qos_overrides.*`` parameter that no publisher or subscription applied
        (a misspelt topic or policy, or a topic the node does not have).

        Raises
        ------
        ParameterError
            Naming the overrides.
        """
        unused = sorted(
            name
            for name in {*self._parameter_overrides, *self._command_line}
            if name.startswith("qos_overrides.") and not self.has_parameter(name)
        )
        if unused:
            raise ParameterError(
                f"QoS override(s) {', '.join(unused)} match no publisher or subscription "
                "policy of this node and would not be applied; the node's topics: "
                + ", ".join(
                    sorted(
                        {
                            n.split(".")[1]
                            for n in self._parameters
                            if n.startswith("qos_overrides.")
                        }
                    )
                )
            )

    def _on_image(self, msg: Image | CompressedImage) -> None:
        stamp_ns = messages.stamp_to_ns(msg.header.stamp)
        self._diagnostics.input_seen(
            msg.header.frame_id, stamp_ns, self.get_clock().now().nanoseconds
        )
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
        self._infos.add(
            messages.stamp_to_ns(msg.header.stamp), (intrinsics, msg.header.frame_id, msg)
        )
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

    def _snapshot(self, msg: Image | CompressedImage | None = None) -> Snapshot:
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
            )

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
            self.get_logger().warning(
                f"camera_info frame_id {info_frame!r} differs from the image's {image_frame!r} "
                "(counted in /diagnostics as camera_info_frame_mismatches)",
                throttle_duration_sec=10.0,
            )
        return intrinsics, None

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
        # The camera_info the frame was processed with (paired by stamp, as the worker did).
        entry = self._infos.nearest(
            messages.stamp_to_ns(msg.header.stamp), round(config.camera_info_tolerance_s * 1e9)
        )
        self._outputs.publish(
            msg.header,
            image,
            frame,
            reference_camera,
            config.publish_reference,
            config.publish_overlay,
            score_map,
            None if entry is None else entry[2],
            config.score_full_resolution,
            config.overlay_full_resolution,
        )

    def destroy_node(self) -> None:
        """Stop the processing thread (nothing is published after), then destroy the node."""
        worker = getattr(self, "_worker", None)
        if worker is not None:
            worker.stop()
        super().destroy_node()


def run_node(node_class: type, argv: list[str] | None = None) -> int:
    """Check the command line, then build ``node_class`` and spin it until shutdown.

    Returns the exit status: 0, or 2 (one line on stderr) for an invalid parameter.
    """
    arguments = argv if argv is not None else sys.argv
    try:
        files = check_params_files(arguments)
        check_command_line(arguments)
    except ParameterError as error:
        print(f"{interface.NODE_NAME}: {error}", file=sys.stderr)
        return EXIT_INVALID_PARAMETER
    rclpy.init(args=arguments)
    node = None
    try:
        node = node_class(command_line_parameters(arguments), files)
        rclpy.spin(node)
    except ParameterError as error:
        print(f"{interface.NODE_NAME}: {error}", file=sys.stderr)
        return EXIT_INVALID_PARAMETER
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # A timer that fired while a signal shut the context down (rclpy's RCLError is a
        # RuntimeError): that is the requested shutdown, not a failure.
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run the node until shutdown (``ros2 run allo_mrad_ros mrad_detector``)."""
    return run_node(MradDetectorNode, argv)


if __name__ == "__main__":
    sys.exit(main())
