"""The ``mrad_detector`` node: camera image and pose in, anomaly score, mask and flag out.

One place per concern:

* parameters are declared up front (:mod:`.parameters`) and validated at start and on every
  change into one immutable :class:`~.parameters.NodeConfig`; a rejected change keeps the
  old value and says why;
* :class:`.inputs.NodeInputs` subscribes to the inputs while an output has a subscriber;
  its callbacks only store the newest message, so inputs never wait for processing;
* :class:`.pose_source.PoseSource` looks the camera pose up (TF or topic);
* :class:`.worker.ProcessingWorker` renders (its render thread owns OpenGL) frame n+1 while
  its detect thread detects and publishes frame n with an immutable, swappable ``Pipeline``;
* :class:`.diagnostics.Diagnostics` counts and publishes ``/diagnostics``.

Topic names come from :mod:`allo_mrad_ros.interface`.

Outputs: ``~/score`` (32FC1, 0..255) is the continuous pixel ranking map, the cross score
softly saturated (``mrad.pixel_score: continuous``; ``regions`` gives the paper's sparse map,
zero outside the grown regions), at the detector's processing resolution with
``~/score/camera_info`` (``score_full_resolution``: at the image's); ``~/mask`` (mono8 0/255)
is the union of the grown regions and ``~/anomaly`` the image decision on its area (with
``decision: objects``: whether a confirmed object is in view). ``~/objects`` and
``~/objects/markers`` are the object tracker's objects in the station frame; the reference's
depth the tracker needs is rendered only for frames it tracks.
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSPolicyKind, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import CompressedImage, Image

from allo_mrad_ros import interface
from allo_mrad_ros.pipeline import ProcessedFrame
from allo_mrad_ros.resources import ResourceError, share_path
from allo_mrad_ros.ros import process_tuning, rclpy_compat
from allo_mrad_ros.ros.arguments import (
    check_command_line,
    check_params_files,
    command_line_parameters,
    keys_for_other_nodes,
    unknown_parameters,
)
from allo_mrad_ros.ros.diagnostics import Diagnostics
from allo_mrad_ros.ros.inputs import NodeInputs
from allo_mrad_ros.ros.object_tracking import ObjectsUpdate
from allo_mrad_ros.ros.outputs import Outputs
from allo_mrad_ros.ros.parameters import (
    NodeConfig,
    NodeParameter,
    ParameterError,
    check_mesh,
    declared_parameters,
    node_config_from,
    validate,
)
from allo_mrad_ros.ros.pose_source import PoseSource, tf2_available
from allo_mrad_ros.ros.rclpy_compat import parameter_overrides
from allo_mrad_ros.ros.shutdown import ShutdownSignals
from allo_mrad_ros.ros.worker import ProcessingWorker

# Exit status when a parameter value is invalid (as for a command-line usage error).
EXIT_INVALID_PARAMETER = 2
# Every QoS policy a publisher or subscription can be given is overridable
# (qos_overrides.<topic>.<publisher|subscription>.<policy>); rclpy's default set has three.
QOS_POLICIES = tuple(
    kind
    for kind in QoSPolicyKind
    if kind not in (QoSPolicyKind.INVALID, QoSPolicyKind.AVOID_ROS_NAMESPACE_CONVENTIONS)
)
# How often the node looks whether any output has a subscriber (to subscribe to its inputs),
# where rclpy has no publisher matched event to say so (Humble).
INPUT_POLL_S = 0.25


def station_mesh_uri(mesh: str) -> str:
    """The ``file://`` URI of the station model ``~/objects/markers`` draws (``mesh``, else
    the package's); empty where the package's is not installed."""
    try:
        path = Path(mesh) if mesh else share_path("meshes", "station.glb")
    except ResourceError:
        return ""
    return path.resolve().as_uri()


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
        self._declared = declared_parameters(tf2_available())
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
        # Made here, not in _build: an unconfigured managed node takes parameter changes too.
        self._inputs = NodeInputs(self, config, self._outputs_wanted, qos_overriding)
        self._input_timer = None
        # Whether the inputs follow the outputs' subscribers now (built and, if managed,
        # active), and whether the outputs' matched events say when they change.
        self._watching_inputs = False
        self._matched_events = False
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

        # The callbacks read what is built below; /diagnostics is first published on spin.
        self._diagnostics = Diagnostics(
            self,
            config,
            received=lambda: self._inputs.images.received,
            pose_source=lambda: self._pose_source.kind,
            idle=self._inputs.idle_reason,
            inputs_subscribed=lambda: bool(self._inputs.subscriptions),
            input_publishers=self._inputs.publisher_counts,
            worker_alive=lambda: self._worker is None or self._worker.is_alive(),
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
        self._inputs.pose_source = self._pose_source
        self._worker = ProcessingWorker(
            self._inputs.images,
            self._inputs.snapshot,
            self._inputs.view_of,
            self._publish,
            self._diagnostics,
            self.get_logger(),
            config.pipelined,
            lambda: self._outputs.score.get_subscription_count() > 0,
            self.context.ok,
            max_input_age_s=lambda: self._config.max_input_age_s,
            objects_wanted=self._objects_wanted,
            size_refusal=self._inputs.size_refusal,
        )
        self.get_logger().info(self._tuning)
        self.get_logger().info(
            f"MRAD detector ready: pose from {self._pose_source.kind}, reference scale "
            f"{config.pipeline.render.reference_scale}, grid {config.pipeline.params.grid}, "
            f"{'pipelined' if config.pipelined else 'serial'} processing, "
            f"listening on {self._image_topic}"
        )

    def _start_inputs(self) -> None:
        """Subscribe to the inputs while an output has a subscriber, from now on: on each
        matched event of the outputs' publishers, or, where rclpy has none (Humble), every
        :data:`INPUT_POLL_S`."""
        self._watching_inputs = True
        self._inputs.update()  # unsubscribes the inputs while no output is subscribed
        if not self._matched_events:
            self._input_timer = self.create_timer(INPUT_POLL_S, self._inputs.update)

    def _on_output_matched(self, _status: object) -> None:
        """A subscription matched or left an output: subscribe or drop the inputs."""
        if self._watching_inputs:
            self._inputs.update()

    @property
    def inputs_watched(self) -> bool:
        """Whether the inputs are subscribed and dropped with the outputs' subscribers now."""
        return self._watching_inputs

    def _stop_inputs(self) -> None:
        """Stop watching the outputs and unsubscribe from the image and camera_info."""
        self._watching_inputs = False
        if self._input_timer is not None:
            self.destroy_timer(self._input_timer)
            self._input_timer = None
        self._inputs.unsubscribe()

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
                override = parameter_overrides(self).get(name)
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
        given = {*parameter_overrides(self), *self._command_line}
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
            self._inputs.configure(config)
        if self._matched_events and self._watching_inputs:
            # publish_overlay / publish_reference change what counts as wanted; no matched
            # event says so.
            self._inputs.update()
        return SetParametersResult(successful=True)

    # --- topics -------------------------------------------------------------------------

    def _setup_io(self, state: QoSProfile) -> None:
        # Relative names: they resolve in the node's namespace; QoS overridable at start
        # (qos_overrides.<resolved topic>.subscription.<policy>, read-only parameters).
        image_type, image_topic = Image, interface.IMAGE_INPUT
        base = self.resolve_topic_name(image_topic)
        if self._config.image_transport == "compressed":
            # image_transport's rule: the remapped, resolved base topic + "/compressed".
            image_topic = base + interface.COMPRESSED_SUFFIX
            image_type = CompressedImage
        self._image_topic = self.resolve_topic_name(image_topic)
        # image_transport's CameraSubscriber: camera_info is the sibling of the (remapped)
        # image topic, so remapping the image moves both.
        self._info_topic = camera_info_topic(base)
        self._inputs.open(image_type, self._image_topic, self._info_topic, state, self._diagnostics)
        callbacks = rclpy_compat.matched_event_callbacks(self._on_output_matched)
        self._matched_events = callbacks is not None
        self._outputs = Outputs(
            self,
            overriding=qos_overriding,
            event_callbacks=callbacks,
            station_mesh=station_mesh_uri(self._config.mesh),
        )
        self._inputs.subscribe()  # once at start: declares the inputs' QoS override parameters

    def _objects_wanted(self, config: NodeConfig) -> bool:
        """Whether to track objects in a frame taken with ``config``: on every frame
        (``objects.enabled``, ``decision: objects``) or while ``~/objects`` or
        ``~/objects/markers`` has a subscriber."""
        return config.tracks_every_frame or self._outputs.objects_wanted()

    def _outputs_wanted(self) -> bool:
        """Whether any output has a subscriber (if not, no input is needed)."""
        return self._outputs.wanted(self._config)

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
            for name in {*parameter_overrides(self), *self._command_line}
            if name.startswith("qos_overrides.") and not self.has_parameter(name)
        )
        if unused:
            raise ParameterError(
                f"QoS override(s) {', '.join(unused)} match no publisher or subscription "
                "policy of this node and would not be applied; the node's topics: "
                + ", ".join(
                    sorted(
                        {n.split(".")[0] for n in self.get_parameters_by_prefix("qos_overrides")}
                    )
                )
            )

    # --- outputs ------------------------------------------------------------------------

    def _publish(
        self,
        msg: Image,
        image: np.ndarray,
        frame: ProcessedFrame,
        score_map: bool = True,
        objects: ObjectsUpdate | None = None,
    ) -> None:
        config = self._config
        reference_camera = frame.reference_camera
        if reference_camera is not None and (
            (reference_camera.height, reference_camera.width) != frame.reference.shape[:2]
        ):
            reference_camera = None  # ~/reference/camera_info would not describe ~/reference
        self._outputs.publish(
            msg.header,
            image,
            frame,
            config=config,
            reference_camera=reference_camera,
            # The camera_info the frame was processed with (paired by stamp, as the worker did).
            camera_info=self._inputs.camera_info_of(msg),
            score_map=score_map,
            objects=objects,
        )

    def destroy_node(self) -> None:
        """Stop the processing thread (nothing is published after), then destroy the node."""
        worker = getattr(self, "_worker", None)
        if worker is not None:
            worker.stop()
        super().destroy_node()


def run_node(node_class: type, argv: list[str] | None = None) -> int:
    """Check the command line, then build ``node_class`` and spin it until a signal.

    The first SIGINT or SIGTERM stops the processing threads, then destroys the node, then
    shuts the ROS context down, so no frame is published into a context that is gone; a
    second ends the process at once with status 130 (:mod:`.shutdown`).

    Returns the exit status: 0, or 2 (one line on stderr) for an invalid parameter.
    """
    arguments = argv if argv is not None else sys.argv
    try:
        files = check_params_files(arguments)
        check_command_line(arguments)
    except ParameterError as error:
        print(f"{interface.NODE_NAME}: {error}", file=sys.stderr)
        return EXIT_INVALID_PARAMETER
    signals = ShutdownSignals()  # the signals are the node's from here; rclpy's handlers stay off
    rclpy.init(args=arguments, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = node_class(command_line_parameters(arguments), files)
        _spin_until_signal(node, signals)
    except ParameterError as error:
        print(f"{interface.NODE_NAME}: {error}", file=sys.stderr)
        return EXIT_INVALID_PARAMETER
    except ExternalShutdownException:
        pass  # the context was shut down from elsewhere
    finally:
        if node is not None:
            node.destroy_node()  # the processing threads first: nothing is published after
        rclpy.try_shutdown()
    return 0


def _spin_until_signal(node: Node, signals: ShutdownSignals) -> None:
    """Run the node's callbacks until the first signal (or the context's end)."""
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    # A callback to run is what ends a spin_once (executor.wake only makes it wait again).
    wake = node.create_guard_condition(lambda: None)
    signals.on_request(wake.trigger)
    try:
        while not signals.requested() and rclpy.ok():
            executor.spin_once()
    finally:
        executor.shutdown(timeout_sec=0)
        node.destroy_guard_condition(wake)
    if signals.received is not None:
        node.get_logger().info(
            f"{signals.received.name} received: stopping the processing threads, then the "
            "node (a second signal ends it at once)"
        )


def main(argv: list[str] | None = None) -> int:
    """Run the node until shutdown (``ros2 run allo_mrad_ros mrad_detector``)."""
    return run_node(MradDetectorNode, argv)


if __name__ == "__main__":
    sys.exit(main())
