"""The inputs are subscribed while an output is: on the publishers' matched events where
rclpy has them (Iron and later), by polling where it has not (Humble, forced here)."""

from __future__ import annotations

import time

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image

from allo_mrad_ros.ros import rclpy_compat
from allo_mrad_ros.ros.node import MradDetectorNode

pytestmark = pytest.mark.ros

# A bound on discovery, never a measured time: each wait ends as soon as its condition holds.
DISCOVERY_WAIT_S = 60.0


@pytest.fixture
def ros():
    rclpy.init()
    yield
    rclpy.shutdown()


def _spin_until(executor, condition) -> bool:
    deadline = time.monotonic() + DISCOVERY_WAIT_S
    while not condition() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    return condition()


def _subscribe_and_leave(node, *, topic: str = "/mrad_detector/mask") -> None:
    """A peer subscribes to ``topic``: the inputs follow; it leaves: they are dropped."""
    peer = rclpy.create_node("output_peer")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    executor.add_node(peer)
    try:
        assert not node._inputs.subscriptions
        subscription = peer.create_subscription(Image, topic, lambda _: None, 1)
        assert _spin_until(executor, lambda: bool(node._inputs.subscriptions))
        topics = {s.topic_name for s in node.subscriptions}
        assert {"/arm_camera/image_raw", "/arm_camera/camera_info"} <= topics
        peer.destroy_subscription(subscription)
        assert _spin_until(executor, lambda: not node._inputs.subscriptions)
    finally:
        executor.shutdown(timeout_sec=0)
        peer.destroy_node()


def test_matched_events_subscribe_the_inputs_without_polling(ros):
    assert rclpy_compat.matched_event_callbacks(lambda _: None) is not None  # this rclpy has them
    node = MradDetectorNode(parameter_overrides=[Parameter("pose_source", value="topic")])
    calls = []
    update = node._inputs.update
    node._inputs.update = lambda: (calls.append(1), update())[1]
    try:
        assert node._matched_events and node._input_timer is None  # no timer polls
        _subscribe_and_leave(node)
        assert calls  # the matched callbacks, the only caller left, did it
    finally:
        node.destroy_node()


def test_a_parameter_that_makes_an_output_wanted_subscribes_the_inputs_at_once(ros):
    node = MradDetectorNode(
        parameter_overrides=[
            Parameter("pose_source", value="topic"),
            Parameter("publish_overlay", value=False),
        ]
    )
    peer = rclpy.create_node("overlay_peer")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    executor.add_node(peer)
    try:
        peer.create_subscription(Image, "/mrad_detector/overlay", lambda _: None, 1)
        assert _spin_until(executor, lambda: node._outputs.overlay.get_subscription_count() > 0)
        executor.spin_once(timeout_sec=0.05)
        assert not node._inputs.subscriptions  # ~/overlay is off: nothing is wanted
        node.set_parameters([Parameter("publish_overlay", value=True)])
        assert node._inputs.subscriptions  # no matched event comes for a parameter
    finally:
        executor.shutdown(timeout_sec=0)
        peer.destroy_node()
        node.destroy_node()


def test_without_matched_events_the_node_polls_as_on_humble(ros, monkeypatch):
    monkeypatch.setattr(rclpy_compat, "matched_event_callbacks", lambda on_matched: None)
    node = MradDetectorNode(parameter_overrides=[Parameter("pose_source", value="topic")])
    try:
        assert not node._matched_events and node._input_timer is not None
        _subscribe_and_leave(node)
    finally:
        node.destroy_node()


def test_matched_event_callbacks_follow_the_installed_rclpy(monkeypatch):
    import rclpy.event_handler

    def on_matched(_status):
        pass

    callbacks = rclpy_compat.matched_event_callbacks(on_matched)
    assert callbacks.matched is on_matched

    class HumblePublisherEventCallbacks:  # Humble's signature: no matched event
        def __init__(self, *, deadline=None, liveliness=None, incompatible_qos=None,
                     use_default_callbacks=True):  # fmt: skip
            pass

    monkeypatch.setattr(
        rclpy.event_handler, "PublisherEventCallbacks", HumblePublisherEventCallbacks
    )
    assert rclpy_compat.matched_event_callbacks(on_matched) is None
