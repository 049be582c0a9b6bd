"""``~/detections`` on the wire, as vision_msgs 4.1.1's own definitions read it.

The node's publisher is created with vision_msgs' Python types generated from its ``.msg``
files by the ROS wheels' rosidl generators (test/generated_vision_msgs.py), a message goes
through Fast DDS to a subscription, and rosbags, with types it parsed from the same files,
reads the CDR bytes: each field must hold the region's box in the image's pixels and its
calibrated score in [0, 1], with the image's header.
"""

from __future__ import annotations

import numpy as np
import pytest
import rclpy
import rclpy.executors
from generated_vision_msgs import build, importable, rosbags_typestore
from rclpy.serialization import serialize_message
from std_msgs.msg import Header

from allo_mrad_ros import interface
from allo_mrad_ros.detector.pipeline import DetectionResult
from allo_mrad_ros.detector.regions import extract_regions, region_score
from allo_mrad_ros.pipeline import ProcessedFrame
from allo_mrad_ros.ros.outputs import Outputs
from allo_mrad_ros.ros.parameters import default_config

pytestmark = pytest.mark.ros

DETECTION_ARRAY = "vision_msgs/msg/Detection2DArray"
# The detector works at half the image's size: (45, 80) for a 90 x 160 image.
WORK_SHAPE, IMAGE_SHAPE = (45, 80), (90, 160)
# Two regions, each wider than tall or taller than wide so that swapped sizes show, with
# their peak evidence (0..255) and their box in the image's pixels (x, y, width, height):
# each processing pixel is a 2 x 2 block of the image.
REGIONS = (
    {"rows": slice(5, 8), "cols": slice(10, 25), "peak": 90.0, "box": (20, 10, 30, 6)},
    {"rows": slice(30, 36), "cols": slice(60, 62), "peak": 200.0, "box": (120, 60, 4, 12)},
)


@pytest.fixture(scope="module")
def vision_msgs_site(tmp_path_factory):
    return build(tmp_path_factory.mktemp("vision_msgs"))


def processed_frame() -> ProcessedFrame:
    work_mask = np.zeros(WORK_SHAPE, np.uint8)
    evidence = np.zeros(WORK_SHAPE, np.float32)
    for region in REGIONS:
        work_mask[region["rows"], region["cols"]] = 255
        evidence[region["rows"], region["cols"]] = region["peak"] / 2
        evidence[region["rows"].start, region["cols"].start] = region["peak"]
    mask = np.kron(work_mask, np.ones((2, 2), np.uint8))
    result = DetectionResult(
        work_score=evidence,
        raw_score=np.zeros(WORK_SHAPE, np.float32),
        mask=mask,
        area=int(np.count_nonzero(mask)),
        anomalous=True,
        image_score=float(evidence.max()),
        regions=extract_regions(work_mask, evidence, IMAGE_SHAPE, 8),
    )
    return ProcessedFrame(reference=np.zeros((*WORK_SHAPE, 3), np.uint8), results={"MRAD": result})


def spin_until(node, done, limit: int = 2000) -> None:
    """Spin ``node`` until ``done()``; the bound only stops a broken test from hanging."""
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(node)
    try:
        for _ in range(limit):
            if done():
                return
            executor.spin_once(timeout_sec=0.05)
        raise AssertionError("no ~/detections message arrived")
    finally:
        executor.remove_node(node)


def test_detections_read_with_vision_msgs_own_definitions_hold_boxes_and_scores(
    vision_msgs_site,
):
    store = rosbags_typestore()
    frame = processed_frame()
    regions = frame.primary.regions
    assert [r.box for r in regions] == [r["box"] for r in REGIONS]
    header = Header(frame_id="arm_camera_optical_frame")
    header.stamp.sec, header.stamp.nanosec = 1_700_000_123, 456_789_000
    with importable(vision_msgs_site) as vision:
        rclpy.init()
        node = rclpy.create_node("detections_wire_test")
        try:
            # The node's own output layer creates the publisher, with the generated type.
            outputs = Outputs(node)
            assert outputs.detections is not None
            assert outputs.detections.msg_type is vision.Detection2DArray
            received, raw = [], []
            topic = interface.DETECTIONS_OUTPUT
            node.create_subscription(vision.Detection2DArray, topic, received.append, 10)
            node.create_subscription(vision.Detection2DArray, topic, raw.append, 10, raw=True)
            spin_until(node, lambda: outputs.detections.get_subscription_count() == 2)
            outputs.publish(
                header, np.zeros((*IMAGE_SHAPE, 3), np.uint8), frame, config=default_config()
            )
            spin_until(node, lambda: received and raw)
        finally:
            node.destroy_node()
            rclpy.shutdown()
        data = serialize_message(received[0])
    # What arrived is what went on the wire, and rosbags' types read every byte of it.
    assert data == raw[0]
    array = store.deserialize_cdr(data, DETECTION_ARRAY)
    assert store.serialize_cdr(array, DETECTION_ARRAY) == data
    assert array.header.frame_id == "arm_camera_optical_frame"
    assert (array.header.stamp.sec, array.header.stamp.nanosec) == (1_700_000_123, 456_789_000)
    assert len(array.detections) == len(REGIONS)
    for index, (detection, region, expected) in enumerate(
        zip(array.detections, regions, REGIONS, strict=True)
    ):
        assert detection.header.frame_id == "arm_camera_optical_frame"
        assert detection.header.stamp.sec == 1_700_000_123
        assert detection.header.stamp.nanosec == 456_789_000
        assert detection.id == str(index)
        x, y, width, height = expected["box"]
        bbox = detection.bbox
        # vision_msgs: the box's centre and its total size, in the image's pixels.
        assert (bbox.center.position.x, bbox.center.position.y) == (x + width / 2, y + height / 2)
        assert bbox.center.theta == 0.0
        assert (bbox.size_x, bbox.size_y) == (width, height)
        (result,) = detection.results
        assert result.hypothesis.class_id == "anomaly"
        # In [0, 1] as vision_msgs asks: the region's calibrated score, not its 0..255 peak.
        assert result.hypothesis.score == region.score == region_score(expected["peak"])
        assert 0.0 <= result.hypothesis.score <= 1.0
        pose = result.pose.pose
        assert (pose.position.x, pose.position.y, pose.orientation.w) == (0.0, 0.0, 1.0)
    scores = [d.results[0].hypothesis.score for d in array.detections]
    assert scores[0] < scores[1]  # monotone in the evidence: 90 ranks below 200
