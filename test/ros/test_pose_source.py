"""Camera pose and stamped inputs: tf_timeout_s for TF, frame ids checked against the station.

tf2_ros is not installed on the pip route; the tf2 stand-in (test/tf2_stand_in.py, written from
tf2's code) takes its place and records what the node asks TF.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest
import rclpy
import tf2_stand_in
from geometry_msgs.msg import PoseStamped, TransformStamped
from rclpy.qos import QoSProfile
from std_msgs.msg import Header
from visualization_msgs.msg import Marker

from allo_mrad_ros.render import CelestialBody
from allo_mrad_ros.ros.messages import MessageError
from allo_mrad_ros.ros.pose_source import PoseSource

pytestmark = pytest.mark.ros

# T_station_world of the TF tree given to the tf2 stand-in: 10 m along x, a quarter turn
# about z; the camera sits at world's origin.
QUARTER_TURN_Z = (0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5))


def stand_in_tf(monkeypatch):
    """Install the tf2 stand-in (test/tf2_stand_in.py) as tf2_ros; return the function that
    fills a PoseSource's buffer with the tree above, as TransformListener would."""
    monkeypatch.setitem(sys.modules, "tf2_ros", tf2_stand_in.module())

    def fill(poses: PoseSource) -> None:
        world = TransformStamped()
        world.header.frame_id, world.child_frame_id = "station", "world"
        world.transform.translation.x = 10.0
        r = world.transform.rotation
        r.x, r.y, r.z, r.w = QUARTER_TURN_Z
        poses._tf_buffer.set_transform_static(world, "test")
        camera = TransformStamped()
        camera.header.frame_id, camera.child_frame_id = "world", "arm_camera_optical_frame"
        camera.transform.rotation.w = 1.0
        poses._tf_buffer.set_transform_static(camera, "test")

    return fill


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
    fill = stand_in_tf(monkeypatch)
    poses = source(node, "topic", [])
    fill(poses)
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
    fill = stand_in_tf(monkeypatch)
    poses = source(node, "tf", [])
    fill(poses)
    header = Header(frame_id="arm_camera_optical_frame")
    pose = poses.lookup(header, 0.05, 0.75)
    assert pose is not None and pose[0, 3] == 10.0
    assert poses._tf_buffer.lookups[-1] == ("station", "arm_camera_optical_frame", 0, 0.75)


def test_a_topic_pose_arriving_after_the_image_is_waited_for_up_to_tf_timeout_s(node):
    # On a loaded machine (a flood of frames) the pose callback may run well after the image's.
    import threading

    poses = source(node, "topic", [])
    late = threading.Timer(0.2, poses._on_pose, [pose_msg("station", 1.0)])
    late.start()
    try:
        # Waits up to 30 s (a bound for a loaded machine, where the timer may fire late);
        # it returns as soon as the pose has come.
        pose = poses.lookup(pose_msg("", 0).header, 0.01, 30.0)
    finally:
        late.join()
    assert pose is not None and pose[0, 3] == 1.0
    elsewhere = Header()
    elsewhere.stamp.sec = 100
    assert poses.lookup(elsewhere, 0.01, 0.0) is None  # no pose near this stamp
