"""Two mrad_detector nodes on one DDS graph, one per namespace (two cameras side by side).

``cam1`` takes raw images and publishes its reference; ``cam2`` takes compressed images
(``image_transport:=compressed``, png and jpeg). Each node's inputs and outputs resolve in
its own namespace, so each feed sees only its own node's results. Waits are for conditions,
with generous timeouts: the machine may be loaded.
"""

import time

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import CameraInfo
from visualization_msgs.msg import ImageMarker

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render import ReferenceRenderer
from allo_mrad_ros.ros.node_process import start_node, stop_node
from harness.feed import CameraFeed

pytestmark = pytest.mark.ros

INTRINSICS = CameraIntrinsics(320, 180, 222.2, 222.2, 160.0, 90.0)
SUN = (0.3, -0.5, 0.8)
T0 = 1_900_000_000 * 10**9
BOX = (slice(60, 110), slice(180, 240))  # rows, columns of the pasted anomaly


@pytest.fixture(scope="module")
def frames():
    pose = look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0])
    with ReferenceRenderer(None, INTRINSICS, scale=1.0) as camera:
        clean = camera.render(pose, SUN).rgb
    anomalous = clean.copy()
    anomalous[BOX] = (230, 180, 40)
    return pose, clean, anomalous


@pytest.fixture(scope="module")
def graph(tmp_path_factory):
    """Two node processes (cam1 raw, cam2 compressed) and a feed for each namespace."""
    logs = tmp_path_factory.mktemp("namespaces")
    rclpy.init()
    feeds = {
        "cam1": CameraFeed(INTRINSICS, namespace="cam1"),
        "cam2": CameraFeed(INTRINSICS, namespace="cam2", compression="png"),
    }
    feeds["cam1"].subscribe("result", DiagnosticArray)
    feeds["cam1"].subscribe("regions", ImageMarker)
    feeds["cam1"].subscribe("reference/camera_info", CameraInfo)
    feeds["cam1"].subscribe("reference")
    processes = {
        "cam1": start_node(
            logs / "cam1.log",
            # A 320x180 camera: reference and query processed at half size, not the
            # defaults' 1/8 and 1/4, which suit 1080p.
            "reference_scale:=0.5",
            "mrad.process_scale:=0.5",
            "publish_reference:=true",
            "diagnostics_period_s:=0.5",
            "max_input_age_s:=0.0",  # frames counted: none dropped for age on a slow machine
            namespace="cam1",
        ),
        "cam2": start_node(
            logs / "cam2.log",
            "reference_scale:=0.5",
            "mrad.process_scale:=0.5",
            "image_transport:=compressed",
            "diagnostics_period_s:=0.5",
            "max_input_age_s:=0.0",
            namespace="cam2",
        ),
    }
    try:
        for name, feed in feeds.items():
            assert feed.wait_for_node(120.0), (logs / f"{name}.log").read_text()
        yield feeds, processes, logs
    finally:
        for process in processes.values():
            stop_node(process)
        for feed in feeds.values():
            feed.node.destroy_node()
        rclpy.shutdown()


def spin_all(feeds, seconds):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for feed in feeds.values():
            rclpy.spin_once(feed.node, timeout_sec=0.01)


def publish_until_mask(feeds, name, stamp, rgb, pose, timeout=90.0):
    """Publish one frame on ``name``'s feed (again, for discovery) until its mask arrives."""
    feed = feeds[name]
    end = time.monotonic() + timeout
    while time.monotonic() < end and stamp not in feed.received["mask"]:
        feed.publish_frame(stamp, rgb, pose, SUN)
        spin_all(feeds, 0.5)
    return feed.received["mask"].get(stamp)


def mask_of(msg):
    return np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.width)


def finds_the_box(mask):
    """The mask marks the pasted box and (almost) nothing else."""
    outside = np.ones_like(mask, bool)
    outside[BOX] = False
    return (mask[BOX] > 0).mean() > 0.1 and (mask[outside] > 0).mean() < 0.02


def test_two_nodes_in_two_namespaces_each_answer_only_their_camera(graph, frames):
    feeds, processes, logs = graph
    pose, clean, anomalous = frames
    first = publish_until_mask(feeds, "cam1", T0 + 1, anomalous, pose)
    assert first is not None, (logs / "cam1.log").read_text()
    second = publish_until_mask(feeds, "cam2", T0 + 2, clean, pose)
    assert second is not None, (logs / "cam2.log").read_text()
    spin_all(feeds, 1.0)
    assert T0 + 2 not in feeds["cam1"].received["mask"]
    assert T0 + 1 not in feeds["cam2"].received["mask"]
    assert finds_the_box(mask_of(first)) and not mask_of(second).any()
    assert all(p.poll() is None for p in processes.values())
    # Each node's /diagnostics status is named by its namespace.
    for name, feed in feeds.items():
        assert feed.wait_for(lambda f=feed: bool(f.diagnostic_values()), 30.0), name
        assert feed.diagnostics[-1].status[0].name == f"{name}/mrad_detector: pipeline"


def test_compressed_input_png_and_jpeg_is_decoded_and_detected(graph, frames):
    feeds, _, logs = graph
    pose, _, anomalous = frames
    feed = feeds["cam2"]
    for offset, compression in ((10, "png"), (11, "jpeg")):
        feed.compression = compression
        msg = publish_until_mask(feeds, "cam2", T0 + offset, anomalous, pose)
        assert msg is not None, (compression, (logs / "cam2.log").read_text())
        mask = mask_of(msg)
        assert mask.shape == (180, 320)
        assert finds_the_box(mask), compression
    feed.compression = "png"


def test_stamped_result_regions_and_reference_camera_info(graph, frames):
    feeds, _, logs = graph
    pose, _, anomalous = frames
    feed = feeds["cam1"]
    stamp = T0 + 20
    assert publish_until_mask(feeds, "cam1", stamp, anomalous, pose) is not None
    for topic in ("result", "regions", "reference", "reference/camera_info"):
        assert feed.wait_for(lambda t=topic: stamp in feed.received[t], 30.0), (
            topic,
            (logs / "cam1.log").read_text(),
        )
    status = feed.received["result"][stamp].status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert values["anomalous"] == "true" and status.level == status.WARN
    assert int(values["area_px"]) > 0.1 * 50 * 60
    marker = feed.received["regions"][stamp]
    assert (
        marker.header.frame_id == "arm_camera_optical_frame"
        and marker.type == ImageMarker.LINE_LIST
    )
    xs = [p.x for p in marker.points]
    ys = [p.y for p in marker.points]
    # The outlines span exactly the mask's marked pixels, which lie on the pasted box.
    rows, cols = np.nonzero(mask_of(feed.received["mask"][stamp]))
    assert (min(xs), max(xs), min(ys), max(ys)) == (
        cols.min(),
        cols.max() + 1,
        rows.min(),
        rows.max() + 1,
    )
    # Hysteresis growth keeps the blur's rim (2 SD of the 5 px blur) around the object.
    rim = 10
    assert BOX[1].start - rim <= min(xs) and max(xs) <= BOX[1].stop + rim
    assert BOX[0].start - rim <= min(ys) and max(ys) <= BOX[0].stop + rim
    reference = feed.received["reference"][stamp]
    info = feed.received["reference/camera_info"][stamp]
    assert (info.width, info.height) == (reference.width, reference.height) == (160, 90)
    assert info.k[0] == pytest.approx(111.1, rel=0.01)
    assert info.header.frame_id == reference.header.frame_id == "arm_camera_optical_frame"


def test_no_subscriber_no_processing_and_the_inputs_are_unsubscribed(graph, frames):
    feeds, _, logs = graph
    pose, clean, _ = frames
    feed = feeds["cam2"]
    for topic in list(feed.subscriptions):
        feed.unsubscribe(topic)
    stamp = T0 + 30

    def idle():
        status = feed.diagnostics[-1].status[0] if feed.diagnostics else None
        return status is not None and status.message.startswith("idle")

    def unsubscribed():
        # The node looks for subscribers a few times a second; the diagnostics may say
        # idle one message before the inputs are dropped. Our publisher learns that the
        # node's subscription is gone by discovery, apart from (and maybe after) the
        # diagnostics that say so.
        return (
            idle()
            and feed.diagnostic_values().get("inputs_subscribed") == "false"
            and feed.pub_image.get_subscription_count() == 0
        )

    end = time.monotonic() + 60.0
    while time.monotonic() < end and not unsubscribed():
        spin_all(feeds, 0.5)
    assert idle(), (feed.diagnostic_values(), (logs / "cam2.log").read_text())
    assert feed.diagnostic_values()["inputs_subscribed"] == "false"
    assert feed.pub_image.get_subscription_count() == 0  # no image crosses DDS for nobody
    processed = int(feed.diagnostic_values()["frames_processed"])
    for _ in range(4):
        stamp += 1
        feed.publish_frame(stamp, clean, pose, SUN)
        spin_all(feeds, 0.5)
    spin_all(feeds, 1.5)
    assert int(feed.diagnostic_values()["frames_processed"]) == processed
    feed.subscribe("mask")
    assert publish_until_mask(feeds, "cam2", stamp + 1, clean, pose) is not None
