"""Camera pose and stamped inputs: tf_timeout_s for TF, frame ids checked against the station.

tf2_ros is not installed on the pip route; a stand-in module records what the node asks TF.
"""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PoseStamped, TransformStamped
from rclpy.qos import QoSProfile
from std_msgs.msg import Header
from visualization_msgs.msg import Marker

from allo_mrad_ros.render import CelestialBody
from allo_mrad_ros.ros.messages import MessageError
from allo_mrad_ros.ros.pose_source import PoseSource

pytestmark = pytest.mark.ros

# T_station_world of the stand-in TF tree: 10 m along x, a quarter turn about z.
QUARTER_TURN_Z = (0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5))


class FakeTfModule(types.ModuleType):
    class LookupException(Exception):
        pass

    class ConnectivityException(Exception):
        pass

    class ExtrapolationException(Exception):
        pass

    def __init__(self) -> None:
        super().__init__("tf2_ros")
        self.calls: list[tuple[str, str, float]] = []
        module = self

        class Buffer:
            def lookup_transform(self, target, source, time, timeout):
                module.calls.append((target, source, timeout.nanoseconds / 1e9))
                if source not in ("world", "arm_camera_optical_frame"):
                    raise module.LookupException(f"no frame {source}")
                msg = TransformStamped()
                msg.transform.translation.x = 10.0
                r = msg.transform.rotation
                r.x, r.y, r.z, r.w = QUARTER_TURN_Z
                return msg

        self.Buffer = Buffer
        self.TransformListener = lambda buffer, node: None


@pytest.fixture
def node():
    rclpy.init()
    created = rclpy.create_node("pose_source_test")
    yield created
    created.destroy_node()
    rclpy.shutdown()


def source(node, kind, reported):
    return PoseSource(node, kind, "station", "", QoSProfile(depth=5), reported.append)


def pose_msg(frame_id: str, x: float) -> PoseStamped:
    msg = PoseStamped()
    msg.header.frame_id = frame_id
    msg.header.stamp.sec = 5
    msg.pose.position.x = x
    msg.pose.orientation.w = 1.0
    return msg


def test_poses_in_another_frame_are_rejected_with_a_counted_reason_without_tf(node):
    reported = []
    poses = source(node, "topic", reported)
    poses._on_pose(pose_msg("world", 1.0))
    assert [e.cause for e in reported] == ["pose_frame"]
    assert "'world', not station_frame 'station'" in str(reported[0])
    assert poses.lookup(pose_msg("", 0).header, 0.0, 0.0) is None
    poses._on_pose(pose_msg("station", 1.0))
    assert poses.lookup(pose_msg("", 0).header, 0.0, 0.0)[0, 3] == 1.0


def test_sun_and_bodies_in_another_frame_are_rejected_without_tf(node):
    poses = source(node, "topic", [])
    with pytest.raises(MessageError) as caught:
        poses.in_station(Header(frame_id=""), np.array([1.0, 0.0, 0.0]), "sun")
    assert caught.value.cause == "sun_frame"
    marker = Marker(ns="earth", type=Marker.SPHERE, action=Marker.ADD)
    marker.header.frame_id = "map"
    with pytest.raises(MessageError) as caught:
        poses.bodies_in_station([marker], (CelestialBody("earth", (1.0, 0.0, 0.0), 1.0),))
    assert caught.value.cause == "bodies_frame"


def test_inputs_in_another_frame_are_transformed_through_tf(node, monkeypatch):
    tf = FakeTfModule()
    monkeypatch.setitem(sys.modules, "tf2_ros", tf)
    poses = source(node, "topic", [])
    poses._on_pose(pose_msg("world", 1.0))
    pose = poses.lookup(pose_msg("", 0).header, 0.0, 0.0)
    np.testing.assert_allclose(pose[:3, 3], [10.0, 1.0, 0.0], atol=1e-9)
    sun = poses.in_station(Header(frame_id="world"), np.array([1.0, 0.0, 0.0]), "sun")
    np.testing.assert_allclose(sun, [0.0, 1.0, 0.0], atol=1e-9)
    marker = Marker(ns="moon", type=Marker.SPHERE, action=Marker.ADD)
    marker.header.frame_id = "world"
    (moon,) = poses.bodies_in_station([marker], (CelestialBody("moon", (0.0, 2.0, 0.0), 1.0),))
    np.testing.assert_allclose(moon.centre, [8.0, 0.0, 0.0], atol=1e-9)
    with pytest.raises(MessageError, match="no TF transform"):
        poses.in_station(Header(frame_id="elsewhere"), np.array([1.0, 0.0, 0.0]), "sun")


def test_tf_lookup_waits_tf_timeout_s_not_pose_tolerance_s(node, monkeypatch):
    tf = FakeTfModule()
    monkeypatch.setitem(sys.modules, "tf2_ros", tf)
    poses = source(node, "tf", [])
    header = Header(frame_id="arm_camera_optical_frame")
    pose = poses.lookup(header, 0.05, 0.75)
    assert pose is not None and pose[0, 3] == 10.0
    assert tf.calls[-1] == ("station", "arm_camera_optical_frame", 0.75)


def test_a_topic_pose_arriving_after_the_image_is_waited_for_up_to_tf_timeout_s(node):
    # On a loaded machine (a flood of frames) the pose callback may run well after the image's.
    import threading

    poses = source(node, "topic", [])
    late = threading.Timer(0.2, poses._on_pose, [pose_msg("station", 1.0)])
    late.start()
    try:
        pose = poses.lookup(pose_msg("", 0).header, 0.01, 5.0)
    finally:
        late.join()
    assert pose is not None and pose[0, 3] == 1.0
    elsewhere = Header()
    elsewhere.stamp.sec = 100
    assert poses.lookup(elsewhere, 0.01, 0.0) is None  # no pose near this stamp
