"""The managed variant: configure builds, activate starts processing, cleanup removes."""

from __future__ import annotations

import pytest
import rclpy
from lifecycle_msgs.msg import State
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter

from allo_mrad_ros.ros.lifecycle import MradDetectorLifecycleNode

pytestmark = pytest.mark.ros


@pytest.fixture
def ros():
    rclpy.init()
    yield
    rclpy.shutdown()


def _topics(node) -> set[str]:
    return {s.topic_name for s in node.subscriptions} | {p.topic_name for p in node.publishers}


def test_configure_builds_activate_starts_and_cleanup_removes(ros):
    node = MradDetectorLifecycleNode(parameter_overrides=[Parameter("pose_source", value="topic")])
    try:
        assert node._worker is None and "/mrad_detector/mask" not in _topics(node)
        assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS
        assert node._state_machine.current_state[0] == State.PRIMARY_STATE_INACTIVE
        assert node._worker is not None and node._worker.is_alive()
        assert "/mrad_detector/mask" in _topics(node)
        assert not node.inputs_watched  # inactive: no input is watched or subscribed
        assert "/arm_camera/image_raw" not in _topics(node)
        assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
        assert node.inputs_watched
        assert node.trigger_deactivate() == TransitionCallbackReturn.SUCCESS
        assert not node.inputs_watched and not node._inputs.subscriptions
        worker = node._worker
        assert node.trigger_cleanup() == TransitionCallbackReturn.SUCCESS
        assert not worker.is_alive() and node._worker is None
        assert "/mrad_detector/mask" not in _topics(node)
    finally:
        node.destroy_node()


def test_a_bad_mesh_fails_configure_with_one_line(ros, tmp_path, capfd):
    mesh = tmp_path / "station.glb"
    mesh.write_bytes(b"")
    node = MradDetectorLifecycleNode(
        parameter_overrides=[
            Parameter("pose_source", value="topic"),
            Parameter("mesh", value=str(mesh)),
        ]
    )
    try:
        assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
        assert "configure failed: mesh" in capfd.readouterr().err
        assert "/mrad_detector/mask" not in _topics(node)
    finally:
        node.destroy_node()


def _pose_subscriptions(peer, node_name: str) -> int:
    """Subscriptions of ``node_name`` on the pose topic, as another node sees the graph."""
    return sum(
        1
        for info in peer.get_subscriptions_info_by_topic("/arm_camera/pose")
        if info.node_name == node_name
    )


def test_a_second_configure_leaves_the_pose_topic_unsubscribed_while_inactive(ros):
    node = MradDetectorLifecycleNode(parameter_overrides=[Parameter("pose_source", value="topic")])
    peer = rclpy.create_node("pose_peer")
    try:
        for transition in ("configure", "activate", "deactivate", "cleanup", "configure"):
            assert getattr(node, f"trigger_{transition}")() == TransitionCallbackReturn.SUCCESS
        assert node._state_machine.current_state[0] == State.PRIMARY_STATE_INACTIVE
        # The node's own view and the graph's, read by a peer (the DDS discovery view).
        assert "/arm_camera/pose" not in _topics(node)
        assert _pose_subscriptions(peer, "mrad_detector") == 0
        assert node.count_subscribers("/arm_camera/pose") == 0
        assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
        node._inputs.subscribe()  # what an output's subscriber brings about
        assert [s.topic_name for s in node.subscriptions].count("/arm_camera/pose") == 1
        node._inputs.unsubscribe()
        assert "/arm_camera/pose" not in _topics(node)
    finally:
        peer.destroy_node()
        node.destroy_node()
