"""The node's inputs on their own: which Sun lights a frame when a parameter and a topic
both give one."""

import dataclasses
import types

import numpy as np
import pytest
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Float32

from allo_mrad_ros.ros.inputs import NodeInputs, matched_publishers
from allo_mrad_ros.ros.parameters import detector_parameters, node_config_from, node_parameters

pytestmark = pytest.mark.ros


def _config(**changes):
    declared = {**node_parameters(False), **detector_parameters()}
    config = node_config_from({name: p.default for name, p in declared.items()})
    return dataclasses.replace(config, **changes)


def test_a_sun_parameter_applies_until_a_sun_topic_has_given_one():
    # Parameters, the Sun strength callback and snapshots never reach the node.
    inputs = NodeInputs(
        object(),
        _config(sun_direction=(0.0, 0.0, 1.0), sun_strength=1.0),
        lambda: True,
        QoSOverridingOptions.with_default_policies,
    )
    inputs.configure(_config(sun_direction=(0.0, 1.0, 0.0), sun_strength=2.0))
    state = inputs.snapshot()
    assert np.allclose(state.sun_direction, (0.0, 1.0, 0.0)) and state.sun_strength == 2.0
    inputs.on_sun_strength(Float32(data=3.0))
    inputs.configure(_config(sun_direction=(1.0, 0.0, 0.0), sun_strength=4.0))
    state = inputs.snapshot()
    assert np.allclose(state.sun_direction, (0.0, 1.0, 0.0)) and state.sun_strength == 3.0
    assert state.config.sun_strength == 4.0  # the settings themselves are the new ones
    assert np.allclose(inputs.sun_direction, (0.0, 1.0, 0.0))


class _Graph:
    """A node's graph count, as Humble's rclpy gives it."""

    def __init__(self, publishers):
        self.publishers = publishers

    def count_publishers(self, topic):
        return self.publishers[topic]


class _HumbleSubscription:
    """A subscription of Humble's rclpy: no matched-publisher count of its own."""

    topic_name = "/arm_camera/image_raw"


class _Subscription(_HumbleSubscription):
    def __init__(self, matched):
        self.matched = matched

    def get_publisher_count(self):
        return self.matched


def test_matched_publishers_are_the_subscriptions_own_count_where_rclpy_has_one():
    graph = _Graph({"/arm_camera/image_raw": 2})
    # The subscription's side has matched none yet although the graph shows two publishers:
    # its count, not the graph's, says whether an image would arrive.
    assert matched_publishers(graph, _Subscription(0)) == 0
    assert matched_publishers(graph, _Subscription(1)) == 1
    assert matched_publishers(graph, _HumbleSubscription()) == 2


def test_publisher_counts_are_zero_while_the_inputs_are_unsubscribed():
    inputs = NodeInputs(
        object(), _config(), lambda: False, QoSOverridingOptions.with_default_policies
    )
    assert inputs.publisher_counts() == {"image": 0, "camera_info": 0}


def _camera_info(width, height, sec):
    info = CameraInfo(width=width, height=height)
    info.header.stamp.sec = sec
    info.k = [200.0, 0.0, width / 2, 0.0, 200.0, height / 2, 0.0, 0.0, 1.0]
    info.p = [200.0, 0.0, width / 2, 0.0, 0.0, 200.0, height / 2, 0.0, 0.0, 0.0, 1.0, 0.0]
    return info


def _raw_image(width, height, sec):
    image = Image(width=width, height=height, encoding="rgb8", step=3 * width)
    image.header.stamp.sec = sec
    return image


def test_the_size_refusal_compares_a_raw_image_with_the_camera_info_of_its_stamp():
    inputs = NodeInputs(
        object(), _config(), lambda: True, QoSOverridingOptions.with_default_policies
    )
    assert inputs.size_refusal(_raw_image(4000, 4000, 5)) is None  # no camera_info yet
    inputs.on_camera_info(_camera_info(320, 180, 5))
    inputs.on_camera_info(_camera_info(640, 360, 9))
    refusal = inputs.size_refusal(_raw_image(4000, 4000, 5))
    assert refusal is not None and refusal.cause == "size"
    assert "4000x4000 differs from camera_info 320x180" in str(refusal)
    assert inputs.size_refusal(_raw_image(320, 180, 5)) is None  # paired by its stamp
    assert inputs.size_refusal(_raw_image(640, 360, 9)) is None
    assert inputs.size_refusal(CompressedImage(format="jpeg")) is None  # size unknown undecoded


class _Node:
    """What the inputs ask of a node to subscribe and unsubscribe."""

    def create_subscription(self, kind, topic, callback, qos, **options):
        return types.SimpleNamespace(topic_name=topic)

    def destroy_subscription(self, subscription):
        pass


class _Counts:
    def report(self, error):
        raise AssertionError(f"reported: {error}")


def test_images_before_a_new_subscription_s_first_camera_info_are_the_start_up_state():
    # The image and camera_info subscriptions made when an output's subscriber returns are
    # matched apart by discovery, as at the node's start: the first images may come before
    # the first camera_info. That is a start-up state each time, not an input error.
    inputs = NodeInputs(
        _Node(), _config(), lambda: True, QoSOverridingOptions.with_default_policies
    )
    inputs.open(Image, "/arm_camera/image_raw", "/arm_camera/camera_info", 10, _Counts())
    inputs.subscribe()
    assert inputs.snapshot(_raw_image(320, 180, 5)).waiting_for_camera_info
    inputs.on_camera_info(_camera_info(320, 180, 5))
    assert inputs.snapshot(_raw_image(320, 180, 5)).camera_problem is None
    inputs.unsubscribe()  # nobody listens: the inputs go
    inputs.subscribe()  # a subscriber again: new subscriptions
    again = inputs.snapshot(_raw_image(320, 180, 9))
    assert again.camera_problem is not None and again.waiting_for_camera_info
    inputs.on_camera_info(_camera_info(320, 180, 9))
    assert inputs.snapshot(_raw_image(320, 180, 9)).camera_problem is None
    # Once this subscription has given a camera_info, an image without its own is an error.
    missing = inputs.snapshot(_raw_image(320, 180, 11))
    assert missing.camera_problem is not None and not missing.waiting_for_camera_info


def test_an_image_stamped_before_the_first_camera_info_is_the_start_up_state():
    # The image subscription may match a moment before the camera_info one: the first
    # images' own camera_infos never arrive, and a later one does. Those images came before
    # the camera_info stream; an image after its start without its own is an input error.
    inputs = NodeInputs(
        _Node(), _config(), lambda: True, QoSOverridingOptions.with_default_policies
    )
    inputs.open(Image, "/arm_camera/image_raw", "/arm_camera/camera_info", 10, _Counts())
    inputs.subscribe()
    inputs.on_camera_info(_camera_info(320, 180, 9))
    early = inputs.snapshot(_raw_image(320, 180, 7))
    assert early.camera_problem is not None and early.waiting_for_camera_info
    late = inputs.snapshot(_raw_image(320, 180, 11))
    assert late.camera_problem is not None and not late.waiting_for_camera_info
    inputs.unsubscribe()
    inputs.subscribe()  # a new stream: its own first camera_info
    inputs.on_camera_info(_camera_info(320, 180, 20))
    assert inputs.snapshot(_raw_image(320, 180, 15)).waiting_for_camera_info
