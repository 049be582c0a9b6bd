"""``~/objects`` and ``~/objects/markers`` on the wire.

``~/objects`` is published by the node's own output layer with vision_msgs' Python types
generated from vision_msgs 4.1.1's ``.msg`` files (test/generated_vision_msgs.py); rosbags,
with types it parsed from the same files, reads the CDR bytes that arrived: the confirmed
objects only, in the station frame with the image's stamp, each with its position, size,
score, covariance and id. The markers are checked against the objects' covariances.
"""

from __future__ import annotations

import numpy as np
import pytest
import rclpy
import rclpy.executors
from generated_vision_msgs import build, importable, rosbags_typestore
from rclpy.serialization import serialize_message
from std_msgs.msg import Header
from visualization_msgs.msg import Marker, MarkerArray

from allo_mrad_ros import interface
from allo_mrad_ros.detector.pipeline import DetectionResult
from allo_mrad_ros.geometry import quaternion_to_matrix
from allo_mrad_ros.objects import TrackedObject
from allo_mrad_ros.pipeline import ProcessedFrame
from allo_mrad_ros.ros.object_messages import (
    LABEL_NS,
    OBJECT_NS,
    STATION_NS,
    UNCERTAINTY_NS,
    UNCERTAINTY_SIGMAS,
)
from allo_mrad_ros.ros.object_tracking import ObjectsUpdate
from allo_mrad_ros.ros.outputs import Outputs
from allo_mrad_ros.ros.parameters import default_config

pytestmark = pytest.mark.ros

DETECTION_ARRAY = "vision_msgs/msg/Detection3DArray"
SHAPE = (90, 160)
ROTATION = quaternion_to_matrix([0.2, -0.1, 0.3, 0.927])


def tracked(object_id: int, state: str, position, covariance, size=0.4, score=0.8):
    return TrackedObject(
        id=object_id,
        state=state,
        position=np.asarray(position, float),
        covariance=np.asarray(covariance, float),
        size=size,
        score=score,
        range_resolved=state == "confirmed",
        in_view=True,
        region=0,
        hits=5,
        first_stamp=1.0,
        last_hit_stamp=2.0,
    )


# A confirmed object with a rotated, elongated covariance; a tentative one; an ended one.
COVARIANCE = ROTATION @ np.diag([0.01, 0.04, 0.25]) @ ROTATION.T
OBJECTS = (
    tracked(3, "confirmed", [1.5, -2.0, 7.25], COVARIANCE, size=0.35, score=0.7),
    tracked(4, "tentative", [0.0, 1.0, 20.0], np.eye(3) * 9.0),
    tracked(5, "ended", [4.0, 4.0, 4.0], np.eye(3) * 0.01),
)


def frame() -> ProcessedFrame:
    result = DetectionResult(
        work_score=np.zeros(SHAPE, np.float32),
        raw_score=np.zeros(SHAPE, np.float32),
        mask=np.zeros(SHAPE, np.uint8),
        area=0,
        anomalous=True,
        image_score=0.0,
        regions=(),
    )
    return ProcessedFrame(reference=np.zeros((*SHAPE, 3), np.uint8), results={"MRAD": result})


@pytest.fixture(scope="module")
def vision_msgs_site(tmp_path_factory):
    return build(tmp_path_factory.mktemp("vision_msgs"))


def spin_until(node, done, limit: int = 2000) -> None:
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(node)
    try:
        for _ in range(limit):
            if done():
                return
            executor.spin_once(timeout_sec=0.05)
        raise AssertionError("no message arrived")
    finally:
        executor.remove_node(node)


def test_objects_and_markers_read_with_vision_msgs_own_definitions(vision_msgs_site):
    store = rosbags_typestore()
    header = Header(frame_id="arm_camera_optical_frame")
    header.stamp.sec, header.stamp.nanosec = 1_700_000_123, 456_789_000
    with importable(vision_msgs_site) as vision:
        rclpy.init()
        node = rclpy.create_node("objects_wire_test")
        try:
            outputs = Outputs(node, station_mesh="file:///models/station.glb")
            assert outputs.objects is not None
            assert outputs.objects.msg_type is vision.Detection3DArray
            received, raw, markers = [], [], []
            node.create_subscription(
                vision.Detection3DArray, interface.OBJECTS_OUTPUT, received.append, 10
            )
            node.create_subscription(
                vision.Detection3DArray, interface.OBJECTS_OUTPUT, raw.append, 10, raw=True
            )
            node.create_subscription(
                MarkerArray, interface.OBJECT_MARKERS_OUTPUT, markers.append, 10
            )
            spin_until(
                node,
                lambda: (
                    outputs.objects.get_subscription_count() == 2
                    and outputs.object_markers.get_subscription_count() == 1
                ),
            )
            assert outputs.objects_wanted()
            outputs.publish(
                header,
                np.zeros((*SHAPE, 3), np.uint8),
                frame(),
                config=default_config(),
                objects=ObjectsUpdate(OBJECTS, 0.5),
            )
            spin_until(node, lambda: received and raw and markers)
        finally:
            node.destroy_node()
            rclpy.shutdown()
        data = serialize_message(received[0])
    # The bytes that arrived, as rosbags reads them; the same as the message rclpy made of
    # them, serialised again (the bytes may differ in the alignment padding, which the
    # publisher does not clear).
    array = store.deserialize_cdr(bytes(raw[0]), DETECTION_ARRAY)
    again = store.deserialize_cdr(data, DETECTION_ARRAY)
    assert store.serialize_cdr(again, DETECTION_ARRAY) == store.serialize_cdr(
        array, DETECTION_ARRAY
    )
    assert len(data) == len(raw[0])
    # The station frame, the image's stamp.
    assert array.header.frame_id == interface.STATION_FRAME
    assert (array.header.stamp.sec, array.header.stamp.nanosec) == (1_700_000_123, 456_789_000)
    (detection,) = array.detections  # the confirmed object only
    assert detection.header.frame_id == interface.STATION_FRAME
    assert detection.id == "3"
    centre = detection.bbox.center
    assert (centre.position.x, centre.position.y, centre.position.z) == (1.5, -2.0, 7.25)
    assert (centre.orientation.x, centre.orientation.w) == (0.0, 1.0)
    assert (detection.bbox.size.x, detection.bbox.size.y, detection.bbox.size.z) == (0.35,) * 3
    (result,) = detection.results
    assert result.hypothesis.class_id == "anomaly"
    assert result.hypothesis.score == 0.7
    pose = result.pose.pose
    assert (pose.position.x, pose.position.y, pose.position.z) == (1.5, -2.0, 7.25)
    covariance = np.asarray(result.pose.covariance).reshape(6, 6)
    np.testing.assert_array_equal(covariance[:3, :3], COVARIANCE)
    assert not covariance[3:].any() and not covariance[:, 3:].any()

    # The markers: the station model, then per live object a sphere, its uncertainty and its
    # id; the ended object's deleted.
    (message,) = markers
    by_key = {(m.ns, m.id): m for m in message.markers}
    station = by_key[(STATION_NS, 0)]
    assert station.type == Marker.MESH_RESOURCE
    assert station.mesh_resource == "file:///models/station.glb"
    assert {m.header.frame_id for m in message.markers} == {interface.STATION_FRAME}
    for ns in (OBJECT_NS, UNCERTAINTY_NS, LABEL_NS):
        assert by_key[(ns, 5)].action == Marker.DELETE
        assert by_key[(ns, 3)].action == by_key[(ns, 4)].action == Marker.ADD
    confirmed, tentative = by_key[(OBJECT_NS, 3)], by_key[(OBJECT_NS, 4)]
    assert confirmed.type == Marker.SPHERE and confirmed.scale.x == 0.35
    assert (confirmed.color.r, confirmed.color.g) != (tentative.color.r, tentative.color.g)
    assert by_key[(LABEL_NS, 3)].text == "3 confirmed"
    # The tentative one waits for parallax to place it, and its label says so.
    assert by_key[(LABEL_NS, 4)].text == "4 tentative, range unresolved"
    # The ellipsoid: its axes, rotated by its orientation, are the covariance's principal
    # axes, its diameters 2 x 3 standard deviations along them.
    spread = by_key[(UNCERTAINTY_NS, 3)]
    o = spread.pose.orientation
    axes = quaternion_to_matrix([o.x, o.y, o.z, o.w])
    diameters = np.array([spread.scale.x, spread.scale.y, spread.scale.z])
    rebuilt = axes @ np.diag((diameters / (2 * UNCERTAINTY_SIGMAS)) ** 2) @ axes.T
    np.testing.assert_allclose(rebuilt, COVARIANCE, atol=1e-12)
    np.testing.assert_allclose(sorted(diameters), [0.6, 1.2, 3.0])


def test_between_full_sets_only_the_objects_that_changed_get_markers():
    from dataclasses import replace

    from allo_mrad_ros.ros.object_messages import object_markers

    unchanged = replace(OBJECTS[1], region=None)  # no region hit it this frame
    objects = (OBJECTS[0], unchanged, OBJECTS[2])
    header = Header(frame_id=interface.STATION_FRAME)
    full = object_markers(header, objects, station_mesh="file:///station.glb")
    changed = object_markers(header, objects, changed_only=True)
    assert {m.id for m in full.markers if m.ns == OBJECT_NS} == {3, 4, 5}
    assert {(m.ns, m.id) for m in changed.markers} == {
        (ns, i) for ns in (OBJECT_NS, UNCERTAINTY_NS, LABEL_NS) for i in (3, 5)
    }


def test_a_tentative_object_placed_by_parallax_is_labelled_tentative_only():
    from dataclasses import replace

    from allo_mrad_ros.ros.object_messages import object_markers

    placed = replace(OBJECTS[1], range_resolved=True)
    message = object_markers(Header(frame_id=interface.STATION_FRAME), (placed,))
    (label,) = [m for m in message.markers if m.ns == LABEL_NS]
    assert label.text == f"{placed.id} tentative"
