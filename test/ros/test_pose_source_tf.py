"""``pose_source: tf`` against the tf2 stand-in (``test/tf2_stand_in.py``), which follows
tf2's own lookup rules: interpolation between samples, extrapolation refused, a timeout
waited out, frame names with a leading '/' refused in lookups and stripped from stored
transforms. tf2_ros has no wheel; what still needs a robot is listed in docs/distro.md."""

from __future__ import annotations

import sys
import threading

import numpy as np
import pytest
import rclpy
import tf2_stand_in
from geometry_msgs.msg import TransformStamped
from rclpy.duration import Duration
from rclpy.qos import QoSProfile
from rclpy.time import Time
from scipy.spatial.transform import Rotation, Slerp
from std_msgs.msg import Header

from allo_mrad_ros.ros.messages import MessageError
from allo_mrad_ros.ros.pose_source import PoseSource

pytestmark = pytest.mark.ros

CAMERA = "arm_camera_optical_frame"
SECOND = 10**9
# T_station_base: the arm's base, fixed on the station.
BASE_T, BASE_R = np.array([1.0, 2.0, 3.0]), Rotation.from_euler("z", 90, degrees=True)
# T_base_camera at 1 s and 2 s: the arm moves and turns the camera.
SAMPLES = {
    1 * SECOND: (np.array([0.0, 0.0, 5.0]), Rotation.from_euler("xyz", [10, 20, 30], degrees=True)),
    2 * SECOND: (
        np.array([2.0, -1.0, 5.5]),
        Rotation.from_euler("xyz", [40, -10, 70], degrees=True),
    ),
}


def transform(parent: str, child: str, stamp_ns: int, t, r: Rotation) -> TransformStamped:
    msg = TransformStamped()
    msg.header.frame_id, msg.child_frame_id = parent, child
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, SECOND)
    msg.transform.translation.x, msg.transform.translation.y, msg.transform.translation.z = t
    q = msg.transform.rotation
    q.x, q.y, q.z, q.w = r.as_quat()
    return msg


def matrix(t, r: Rotation) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = r.as_matrix(), t
    return out


def header(stamp_ns: int, frame_id: str = CAMERA) -> Header:
    msg = Header(frame_id=frame_id)
    msg.stamp.sec, msg.stamp.nanosec = divmod(stamp_ns, SECOND)
    return msg


@pytest.fixture
def tf(monkeypatch):
    monkeypatch.setitem(sys.modules, "tf2_ros", tf2_stand_in.module())
    rclpy.init()
    node = rclpy.create_node("pose_source_tf_test")
    source = PoseSource(node, "tf", "station", "", QoSProfile(depth=5), lambda error: None)
    buffer = source._tf_buffer
    # As TransformListener stores /tf_static and /tf; a leading '/' is stripped on storing.
    buffer.set_transform_static(transform("station", "/arm_base", 0, BASE_T, BASE_R), "test")
    for stamp, (t, r) in SAMPLES.items():
        buffer.set_transform(transform("/arm_base", CAMERA, stamp, t, r), "test")
    yield source, buffer
    node.destroy_node()
    rclpy.shutdown()


def test_the_pose_between_two_tf_samples_is_interpolated_and_composed(tf):
    source, _ = tf
    stamp = 1 * SECOND + SECOND // 4
    pose = source.lookup(header(stamp), 0.05, 0.0)
    # The oracle: scipy's slerp and a linear translation, composed with the static link.
    (t0, r0), (t1, r1) = SAMPLES.values()
    rotation = Slerp([0.0, 1.0], Rotation.concatenate([r0, r1]))([0.25])[0]
    expected = matrix(BASE_T, BASE_R) @ matrix(t0 + 0.25 * (t1 - t0), rotation)
    np.testing.assert_allclose(pose, expected, atol=1e-9)
    # At a sample's own stamp, the sample.
    np.testing.assert_allclose(
        source.lookup(header(2 * SECOND), 0.05, 0.0),
        matrix(BASE_T, BASE_R) @ matrix(t1, r1),
        atol=1e-9,
    )


def test_an_image_newer_than_tf_waits_up_to_tf_timeout_s_for_it(tf):
    source, buffer = tf
    asked = threading.Event()
    lookup = buffer.lookup_transform

    def recording(*args, **kwargs):
        asked.set()
        return lookup(*args, **kwargs)

    buffer.lookup_transform = recording
    later = (np.array([4.0, 0.0, 6.0]), Rotation.identity())

    def arrives():  # the transform for the image's time arrives while the node waits
        asked.wait(30)
        buffer.set_transform(transform("arm_base", CAMERA, 4 * SECOND, *later), "test")

    thread = threading.Thread(target=arrives)
    thread.start()
    try:
        pose = source.lookup(header(3 * SECOND), 0.05, 30.0)
    finally:
        thread.join()
    assert pose is not None
    assert buffer.lookups[-1] == ("station", CAMERA, 3 * SECOND, 30.0)


@pytest.mark.parametrize(
    ("stamp", "frame", "error", "text"),
    [
        (3 * SECOND, CAMERA, "ExtrapolationException", "extrapolation into the future"),
        (SECOND // 2, CAMERA, "ExtrapolationException", "extrapolation into the past"),
        (SECOND, "gripper_camera", "LookupException", "does not exist"),
        (SECOND, "island", "ConnectivityException", "not part of the same tree"),
    ],
)
def test_a_pose_tf_cannot_give_is_a_failed_lookup_not_a_crash(tf, stamp, frame, error, text):
    source, buffer = tf
    buffer.set_transform_static(transform("sea", "island", 0, [0, 0, 0], Rotation.identity()), "t")
    with pytest.raises(getattr(tf2_stand_in, error), match=text):
        buffer.lookup_transform("station", frame, Time(nanoseconds=stamp))
    assert source.lookup(header(stamp, frame), 0.05, 0.1) is None  # counted by the node


def test_a_lone_sample_serves_only_its_own_stamp_and_time_zero_is_the_latest(tf):
    _, buffer = tf
    buffer.set_transform(
        transform("station", "tool", 5 * SECOND, [1, 0, 0], Rotation.identity()), "t"
    )
    with pytest.raises(tf2_stand_in.ExtrapolationException, match=r"but only time 5\.000000"):
        buffer.lookup_transform("station", "tool", Time(nanoseconds=6 * SECOND))
    latest = buffer.lookup_transform("station", CAMERA, Time())
    assert (latest.header.stamp.sec, latest.transform.translation.z) == (
        2,
        pytest.approx(3.0 + 5.5),
    )


def test_frame_names_with_a_leading_slash_are_refused_in_lookups(tf):
    source, buffer = tf
    for frame in ("", "/" + CAMERA):
        with pytest.raises(tf2_stand_in.InvalidArgumentException, match="in tf2 frame_ids cannot"):
            buffer.lookup_transform("station", frame, Time(nanoseconds=SECOND))
        # The node says so for the image's frame_id, in one counted line, before asking tf2.
        with pytest.raises(MessageError, match="frame skipped") as caught:
            source.lookup(header(SECOND, frame), 0.05, 0.0)
        assert caught.value.cause == "frame_id"
    # Stored with a leading '/', the frame is found without it (tf2 strips it on storing).
    assert buffer.lookup_transform("arm_base", CAMERA, Time(nanoseconds=SECOND))


def test_the_tf_timeout_is_waited_out_when_nothing_comes(tf):
    _, buffer = tf
    assert not buffer.can_transform(
        "station", CAMERA, Time(nanoseconds=9 * SECOND), Duration(seconds=0.1)
    )
