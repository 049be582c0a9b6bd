"""The node with the object tracker on: a static object seen from a translating camera.

The node runs in this process on an executor thread of its own; a :class:`CameraFeed` peer
sends it frames over DDS on loopback. The camera looks away from the station, so the node's
reference is space; each image is black with a bright disc where a station-frame point
projects, which the detector finds as one region per frame. The camera translates sideways,
so parallax places the point: ``~/objects/markers`` must show a confirmed object there, and
with ``decision: objects`` ``~/anomaly`` is true exactly in the frames that show a confirmed
object (the per-frame decision flags every one). Frames go one at a time and none is
dropped for age (``max_input_age_s: 0``), so a slow machine sees the same frames.
"""

from __future__ import annotations

import threading
from dataclasses import replace

import cv2
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from visualization_msgs.msg import Marker, MarkerArray

from allo_mrad_ros import interface
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.ros.messages import stamp_to_ns
from allo_mrad_ros.ros.node import MradDetectorNode
from allo_mrad_ros.ros.object_messages import LABEL_NS, OBJECT_NS, UNCERTAINTY_NS
from harness.feed import CameraFeed

pytestmark = pytest.mark.ros

INTRINSICS = CameraIntrinsics(320, 180, 222.2, 222.2, 160.0, 90.0)
# The object, 10 m ahead of the camera's path (which runs along x at y = -60, looking -y,
# away from the station at the origin), a little right of and below its centre.
OBJECT = np.array([0.5, -70.0, 0.3])
FRAMES = 8
PERIOD_NS = 100_000_000
T0 = 1_900_000_000 * 10**9
TIMEOUT = 60.0


def pose_at(i: int) -> np.ndarray:
    """Frame ``i``'s camera: 0.5 m further along x each frame (5 m/s at 10 Hz)."""
    eye = np.array([-2.0 + 0.5 * i, -60.0, 0.0])
    return look_at(eye, eye + np.array([0.0, -1.0, 0.0]))


def image_at(pose: np.ndarray) -> np.ndarray:
    """Black, with a bright disc of 4 px radius where :data:`OBJECT` projects."""
    local = pose[:3, :3].T @ (OBJECT - pose[:3, 3])
    u = INTRINSICS.fx * local[0] / local[2] + INTRINSICS.cx
    v = INTRINSICS.fy * local[1] / local[2] + INTRINSICS.cy
    image = np.zeros((INTRINSICS.height, INTRINSICS.width, 3), np.uint8)
    cv2.circle(image, (round(u), round(v)), 4, (230, 230, 230), -1)
    return image


@pytest.fixture(scope="module")
def live():
    rclpy.init()
    node = MradDetectorNode(
        parameter_overrides=[
            Parameter("pose_source", value="topic"),
            Parameter("diagnostics_period_s", value=0.2),
            Parameter("reference_scale", value=0.25),
            Parameter("max_input_age_s", value=0.0),
            Parameter("decision", value="objects"),
        ]
    )
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    feed = CameraFeed(INTRINSICS, outputs=("mask",))
    markers: dict[int, MarkerArray] = {}

    def record(msg: MarkerArray) -> None:
        stamps = {stamp_to_ns(m.header.stamp) for m in msg.markers}
        assert len(stamps) == 1, "one frame's markers (the station model's too) carry its stamp"
        markers[stamps.pop()] = msg

    assert not node._objects_wanted(replace(node._config, decision="frame"))
    feed.node.create_subscription(MarkerArray, f"{feed.output_prefix}/objects/markers", record, 50)
    assert feed.wait_for(
        lambda: node._objects_wanted(replace(node._config, decision="frame")), TIMEOUT
    ), "a subscriber to ~/objects/markers turns tracking on"
    assert feed.wait_for_node(TIMEOUT)
    yield node, feed, markers
    executor.shutdown()
    node.destroy_node()
    feed.node.destroy_node()
    rclpy.shutdown()


def send(feed, markers, node, stamp: int, pose: np.ndarray) -> None:
    """Publish one frame and wait for its mask, markers and flag. The image goes again only
    while the node has not received it (DDS lost it): one it received is processed however
    long that takes on a loaded machine, and a frame sent twice would be tracked twice."""
    flags = len(feed.anomaly_flags)
    images = node._inputs.images
    for _ in range(int(TIMEOUT)):
        received = images.received
        feed.publish_frame(stamp, image_at(pose), pose)
        if feed.wait_for(lambda received=received: images.received > received, 2.0):
            break
    assert feed.wait_for(lambda: stamp in feed.received["mask"] and stamp in markers, TIMEOUT), (
        stamp
    )
    assert feed.wait_for(lambda: len(feed.anomaly_flags) > flags, TIMEOUT), stamp
    assert len(feed.anomaly_flags) == flags + 1


def spheres(array: MarkerArray, ns: str = OBJECT_NS) -> dict[int, Marker]:
    return {m.id: m for m in array.markers if m.ns == ns and m.action == Marker.ADD}


def confirmed(array: MarkerArray) -> dict[int, Marker]:
    """The confirmed objects' spheres (red: the state's colour)."""
    return {i: m for i, m in spheres(array).items() if m.color.g < 0.5}


def test_a_static_object_is_confirmed_where_it_is_and_decision_objects_flags_from_then(live):
    node, feed, markers = live
    stamps = [T0 + i * PERIOD_NS for i in range(FRAMES)]
    for i, stamp in enumerate(stamps):
        send(feed, markers, node, stamp, pose_at(i))
    # The detector finds the disc in every frame: the per-frame decision flags them all.
    assert all(np.any(np.asarray(feed.received["mask"][s].data)) for s in stamps)
    flags = feed.anomaly_flags[-FRAMES:]
    shown = [bool(confirmed(markers[s])) for s in stamps]
    assert flags == shown, (flags, shown)
    # Three hits confirm (objects.confirm_hits), once parallax resolves the range.
    assert not any(flags[:2]) and all(flags[-3:]), flags
    final = confirmed(markers[stamps[-1]])
    assert len(final) == 1
    (sphere,) = final.values()
    position = np.array([sphere.pose.position.x, sphere.pose.position.y, sphere.pose.position.z])
    # Within max(0.3 m, 5 % of its 10 m range) of the truth.
    assert np.linalg.norm(position - OBJECT) < 0.5, position
    assert sphere.header.frame_id == interface.STATION_FRAME
    # Its uncertainty and id go with it.
    assert sphere.id in spheres(markers[stamps[-1]], UNCERTAINTY_NS)
    label = spheres(markers[stamps[-1]], LABEL_NS)[sphere.id]
    assert label.text.startswith(f"{sphere.id} confirmed")
    assert feed.wait_for(
        lambda: int(feed.diagnostic_values().get("objects_confirmed", 0)) == 1, TIMEOUT
    )
    assert "latency_objects_ms_p50" in feed.diagnostic_values()


def test_a_stamp_going_back_ends_every_object_and_the_flag_drops(live):
    node, feed, markers = live
    object_ids = [i for s, array in markers.items() if s >= T0 for i in confirmed(array)]
    assert object_ids, "the first test confirms an object"
    # A bag replayed from its start: an earlier stamp, from the first pose.
    stamp = T0 - 10 * PERIOD_NS
    send(feed, markers, node, stamp, pose_at(0))
    array = markers[stamp]
    deleted = {(m.ns, m.id) for m in array.markers if m.action == Marker.DELETE}
    assert {(OBJECT_NS, object_ids[-1]), (LABEL_NS, object_ids[-1])} <= deleted
    assert not confirmed(array)
    assert feed.anomaly_flags[-1] is False
