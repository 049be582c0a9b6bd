"""The node's parameters: declared with ranges, validated at start and on every change."""

import pytest
import rclpy
from rclpy.parameter import Parameter

from allo_mrad_ros.objects import ObjectParams
from allo_mrad_ros.ros.node import MradDetectorNode
from allo_mrad_ros.ros.parameters import ParameterError

pytestmark = pytest.mark.ros


@pytest.fixture
def node():
    rclpy.init()
    created = MradDetectorNode(
        parameter_overrides=[
            Parameter("mrad.grid", value=6),
            Parameter("pose_source", value="topic"),
        ]
    )
    yield created
    created.destroy_node()
    rclpy.shutdown()


def test_overrides_reach_the_detector(node):
    assert node.get_parameter("mrad.grid").value == 6
    assert node._config.pipeline.params.grid == 6


@pytest.mark.parametrize(
    ("name", "value", "reason"),
    [
        ("mrad.grid", 0, "grid"),
        ("mrad.tolerance", 300.0, "tolerance"),
        ("mrad.kernel_fraction", 0.0, "kernel_fraction must be in (0, 1]"),
        ("mrad.score_scaling", "log", "score_scaling must be one of"),
        ("sun_direction", [0.0, 0.0, 0.0], "sun_direction must not be the zero vector"),
        ("sun_strength", -1.0, "sun_strength"),
        ("reference_scale", 0.5, "read-only"),
        ("decision", "sometimes", "decision must be one of ['frame', 'objects']"),
        ("objects.pixel_sigma", 0.0, "objects.pixel_sigma must be in (0, 1000]"),
        ("objects.confirm_hits", 0, "objects.confirm_hits"),
        ("objects.confirm_window", 2000, "objects.confirm_window"),
        # Valid alone, not with the default confirm_window: the tracker's own rule.
        (
            "objects.confirm_hits",
            ObjectParams().confirm_window + 1,
            f"confirm_hits ({ObjectParams().confirm_window + 1}) must not exceed "
            f"confirm_window ({ObjectParams().confirm_window})",
        ),
        (
            "objects.max_range",
            0.2,
            f"max_range (0.2) must exceed min_range ({ObjectParams().min_range:g})",
        ),
    ],
)
def test_invalid_changes_are_rejected_with_the_reason_and_the_old_value_stays(
    node, name, value, reason
):
    before = node.get_parameter(name).value
    (result,) = node.set_parameters([Parameter(name, value=value)])
    assert not result.successful
    assert reason in result.reason
    assert node.get_parameter(name).value == before


def test_valid_change_is_applied(node):
    (result,) = node.set_parameters([Parameter("mrad.tolerance", value=75.0)])
    assert result.successful
    assert node._config.pipeline.params.tolerance == 75.0


def test_object_tracker_changes_reach_its_params_and_decision_is_applied(node):
    assert node._config.decision == "frame" and not node._config.tracks_every_frame
    results = node.set_parameters(
        [
            Parameter("objects.confirm_window", value=8),
            Parameter("objects.confirm_hits", value=6),
            Parameter("objects.gate_sigma", value=4.0),
            Parameter("decision", value="objects"),
        ]
    )
    assert all(result.successful for result in results), results
    params = node._config.objects.params
    assert (params.confirm_window, params.confirm_hits, params.gate_sigma) == (8, 6, 4.0)
    assert node._config.decision == "objects" and node._config.tracks_every_frame


def test_an_invalid_object_parameter_refuses_to_start():
    rclpy.init()
    try:
        with pytest.raises(ParameterError, match=r"objects\.min_range must be in"):
            MradDetectorNode(
                parameter_overrides=[
                    Parameter("pose_source", value="topic"),
                    Parameter("objects.min_range", value=-1.0),
                ]
            )
    finally:
        rclpy.shutdown()


def test_tf_requested_without_tf2_refuses_to_start():
    pytest.importorskip("rclpy")
    try:
        import tf2_ros  # noqa: F401

        pytest.skip("tf2_ros is installed here")
    except ImportError:
        pass
    rclpy.init()
    try:
        with pytest.raises(ParameterError, match="pose_source is 'tf' but the tf2_ros"):
            MradDetectorNode(parameter_overrides=[Parameter("pose_source", value="tf")])
    finally:
        rclpy.shutdown()


def test_qos_overrides_reach_subscriptions_and_publishers():
    """QoSOverridingOptions: `-p qos_overrides.<topic>.<entity>.<policy>:=...` at start."""
    from rclpy.qos import ReliabilityPolicy

    rclpy.init()
    try:
        node = MradDetectorNode(
            parameter_overrides=[
                Parameter("pose_source", value="topic"),
                Parameter(
                    "qos_overrides./arm_camera/image_raw.subscription.reliability",
                    value="reliable",
                ),
                Parameter("qos_overrides./arm_camera/image_raw.subscription.depth", value=3),
                Parameter("qos_overrides./mrad_detector/mask.publisher.depth", value=1),
            ]
        )
        try:
            # Inputs are subscribed only while an output has a subscriber; the overrides
            # declared at start apply each time they are subscribed again.
            assert not node._inputs.subscriptions
            node._inputs.subscribe()
            image = next(s for s in node.subscriptions if s.topic_name == "/arm_camera/image_raw")
            assert image.qos_profile.reliability == ReliabilityPolicy.RELIABLE
            assert image.qos_profile.depth == 3
            info = next(s for s in node.subscriptions if s.topic_name == "/arm_camera/camera_info")
            assert info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT  # untouched
            assert node._outputs.mask.qos_profile.depth == 1
            assert node._outputs.score.qos_profile.depth == 5
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown()


def test_a_refused_qos_override_names_the_topics_the_node_has():
    rclpy.init()
    try:
        with pytest.raises(ParameterError) as refused:
            MradDetectorNode(
                parameter_overrides=[
                    Parameter("pose_source", value="topic"),
                    Parameter("qos_overrides./mrad_detector/mask.publisher.depht", value=1),
                ]
            )
        topics = str(refused.value).split("the node's topics: ", 1)[1].split(", ")
        assert topics == sorted(topics)
        assert {"/arm_camera/image_raw", "/mrad_detector/mask", "/mrad_detector/score"} <= set(
            topics
        )
        assert all(topic.startswith("/") and "." not in topic for topic in topics)
    finally:
        rclpy.shutdown()


def test_diagnostics_are_built_from_the_node_config_with_their_callbacks():
    rclpy.init()
    try:
        node = MradDetectorNode(
            parameter_overrides=[
                Parameter("pose_source", value="topic"),
                Parameter("hardware_id", value="cam9"),
                Parameter("expected_rate_hz", value=30.0),
                Parameter("input_timeout_s", value=0.5),
            ]
        )
        try:
            diagnostics = node._diagnostics
            assert diagnostics.input_timeout_s == 0.5
            pipeline, rate, _stamp = diagnostics.statuses()
            values = {kv.key: kv.value for kv in pipeline.values}
            assert values["pose_source"] == "topic" and pipeline.hardware_id == "cam9"
            # No output is subscribed: the node is idle on purpose, and says so.
            assert values["inputs_subscribed"] == "false"
            assert pipeline.message.startswith("idle: ")
            assert {kv.key: kv.value for kv in rate.values}["Target frequency (Hz)"] == "30"
            node._worker.stop()
            assert diagnostics.status().message.startswith("processing thread stopped")
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown()


def test_the_image_keeps_one_sample_unless_a_qos_override_says_more():
    """A node short of CPU takes the newest frame, not the oldest of the middleware's queue;
    `qos_overrides.<topic>.subscription.depth` still keeps more. camera_info keeps
    sensor-data's 5, so the one of an image's stamp is still there when the node pairs it."""
    rclpy.init()
    try:
        plain = MradDetectorNode(parameter_overrides=[Parameter("pose_source", value="topic")])
        deeper = MradDetectorNode(
            parameter_overrides=[
                Parameter("pose_source", value="topic"),
                Parameter("qos_overrides./arm_camera/image_raw.subscription.depth", value=2),
                Parameter("qos_overrides./arm_camera/camera_info.subscription.depth", value=8),
            ]
        )
        try:
            depths = {}
            for name, node in (("plain", plain), ("deeper", deeper)):
                node._inputs.subscribe()
                depths[name] = {
                    s.topic_name: s.qos_profile.depth
                    for s in node.subscriptions
                    if s.topic_name in ("/arm_camera/image_raw", "/arm_camera/camera_info")
                }
            assert depths["plain"] == {"/arm_camera/image_raw": 1, "/arm_camera/camera_info": 5}
            assert depths["deeper"] == {"/arm_camera/image_raw": 2, "/arm_camera/camera_info": 8}
        finally:
            plain.destroy_node()
            deeper.destroy_node()
    finally:
        rclpy.shutdown()
