"""The mrad_detector node as its own process, driven over DDS (loopback only) by a peer.

Frames are real renders of the station model; anomalies are objects the model lacks.
"""

import time

import numpy as np
import psutil
import pytest
import rclpy
import trimesh
from sensor_msgs.msg import Image

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render import ExtraObject, ReferenceRenderer
from allo_mrad_ros.ros.messages import fill_image
from allo_mrad_ros.ros.node_process import start_node, stop_node
from harness.feed import CameraFeed

pytestmark = pytest.mark.ros

INTRINSICS = CameraIntrinsics(640, 360, 444.4, 444.4, 320.0, 180.0)
SUN = (0.3, -0.5, 0.8)
T0 = 1_900_000_000 * 10**9  # stamps in 2030
# Longest wait for an output or a diagnostic after a frame's mask: a bound for a loaded
# machine, never a measured time (each wait ends as soon as its condition holds).
LATER_S = 60.0


@pytest.fixture(scope="module")
def scenes():
    """A pose, the clean view, the view with a floating box, and the box's pixels."""
    pose = look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0])
    box = trimesh.creation.box((1.2, 1.2, 1.2))
    box.visual.face_colors = (230, 180, 40, 255)
    box_pose = pose.copy()
    box_pose[:3, 3] = pose[:3, 3] + 8.0 * pose[:3, 2] + 0.8 * pose[:3, 0] - 2.5 * pose[:3, 1]
    with ReferenceRenderer(None, INTRINSICS, scale=1.0) as camera:
        clean = camera.render(pose, SUN).rgb
        anomalous = camera.render(
            pose, SUN, extra_objects=[ExtraObject(box, box_pose)], labels=True
        )
    return pose, clean, anomalous.rgb, anomalous.labels == 2


@pytest.fixture(scope="module")
def ros_peer():
    rclpy.init()
    peer = CameraFeed(INTRINSICS)
    yield peer
    peer.node.destroy_node()
    rclpy.shutdown()


@pytest.fixture(scope="module")
def node_process(tmp_path_factory, ros_peer):
    log = tmp_path_factory.mktemp("node") / "node.log"
    # Every frame is accounted for below: no age limit (test_input_age.py tests the limit).
    process = start_node(
        log, "reference_scale:=0.5", "diagnostics_period_s:=0.5", "max_input_age_s:=0.0"
    )
    assert ros_peer.wait_for_node(60.0), log.read_text()
    yield process, log
    stop_node(process)


def publish_until_output(peer, stamp, rgb, pose, timeout=30.0):
    """Publish one frame (again, for discovery) until the node's mask for it arrives."""
    end = time.monotonic() + timeout
    while time.monotonic() < end and stamp not in peer.received["mask"]:
        peer.publish_frame(stamp, rgb, pose, SUN)
        peer.spin(0.5)
    return peer.received["mask"].get(stamp)


def test_object_absent_from_the_model_is_masked_and_flagged(node_process, ros_peer, scenes):
    pose, _, anomalous, truth = scenes
    mask_msg = publish_until_output(ros_peer, T0 + 1, anomalous, pose)
    assert mask_msg is not None, node_process[1].read_text()
    assert ros_peer.wait_for(lambda: T0 + 1 in ros_peer.received["score"], LATER_S)
    mask = np.frombuffer(mask_msg.data, np.uint8).reshape(360, 640)
    hits = np.count_nonzero((mask > 0) & truth)
    # Hysteresis growth keeps the blur's rim around the object.
    assert hits >= 0.5 * np.count_nonzero(truth) and hits >= 0.7 * np.count_nonzero(mask)
    assert mask_msg.header.frame_id == "arm_camera_optical_frame"
    assert mask_msg.encoding == "mono8" and set(np.unique(mask)) <= {0, 255}
    score_msg = ros_peer.received["score"][T0 + 1]
    assert score_msg.encoding == "32FC1" and score_msg.header.frame_id == "arm_camera_optical_frame"
    # ~/anomaly is its own topic: its message may arrive after the mask's and the score's.
    assert ros_peer.wait_for(lambda: bool(ros_peer.anomaly_flags), LATER_S)
    assert ros_peer.anomaly_flags[-1] is True


def test_clean_frame_is_not_flagged(node_process, ros_peer, scenes):
    pose, clean, _, _ = scenes
    mask_msg = publish_until_output(ros_peer, T0 + 2, clean, pose)
    assert mask_msg is not None, node_process[1].read_text()
    assert not np.frombuffer(mask_msg.data, np.uint8).any()
    assert ros_peer.wait_for(
        lambda: ros_peer.anomaly_flags and ros_peer.anomaly_flags[-1] is False, LATER_S
    )


def test_a_still_camera_reuses_its_reference_and_a_moved_one_renders(
    node_process, ros_peer, scenes
):
    pose, clean, _, _ = scenes

    def count(name):
        return int(ros_peer.diagnostic_values().get(name, 0))

    start = T0 + 5 * 10**9  # stamps no other test uses
    for offset in (0, 1):
        assert publish_until_output(ros_peer, start + offset, clean, pose) is not None
    assert ros_peer.wait_for(lambda: count("references_reused") >= 1, LATER_S), (
        ros_peer.diagnostic_values()
    )
    rendered = count("references_rendered")
    assert rendered >= 1
    moved = look_at([-26.0, -16.0, 8.0], [0.0, 0.0, 0.0])
    # 0.1 s later: beyond the pose lookup's tolerance of the earlier poses, within the age.
    assert publish_until_output(ros_peer, start + 10**8, clean, moved) is not None
    assert ros_peer.wait_for(lambda: count("references_rendered") > rendered, LATER_S)


def test_missing_pose_gives_no_output_and_a_diagnostic(node_process, ros_peer, scenes):
    pose, clean, _, _ = scenes
    stamp = T0 + 3 * 10**9  # seconds away from any pose
    for _ in range(3):
        ros_peer.publish_frame(stamp, clean, None, SUN)
        ros_peer.spin(0.5)
    assert stamp not in ros_peer.received["mask"]
    assert ros_peer.wait_for(
        lambda: int(ros_peer.diagnostic_values().get("pose_lookup_failures", 0)) >= 1, LATER_S
    )
    assert node_process[0].poll() is None
    assert publish_until_output(ros_peer, T0 + 4, clean, pose) is not None  # still working


def malformed_images(clean):
    wrong_step = fill_image(Image(), None, clean, "rgb8")
    wrong_step.step = 100
    unknown = fill_image(Image(), None, clean, "rgb8")
    unknown.encoding = "yuv422_weird"
    small = fill_image(Image(), None, clean[:180, :320], "rgb8")
    for msg in (wrong_step, unknown, small):
        msg.header.frame_id = "arm_camera_optical_frame"
    return {"step": wrong_step, "encoding": unknown, "size": small}


def test_malformed_images_log_one_error_per_cause_and_the_node_survives(
    node_process, ros_peer, scenes
):
    process, log = node_process
    pose, clean, _, _ = scenes
    bad = malformed_images(clean)

    def errors(cause):
        return int(ros_peer.diagnostic_values().get(f"errors_{cause}", 0))

    # Sent once each, the next only once the last one's error is counted: the node keeps one
    # waiting image (a newer one replaces it, counted as dropped), so none stands for another.
    stamp = T0 + 10
    for count in (1, 2):  # twice each: still one log line per cause
        for cause, msg in bad.items():
            stamp += 1
            ros_peer.publish_frame(stamp, None, pose, SUN, image=msg)
            assert ros_peer.wait_for(lambda cause=cause, count=count: errors(cause) >= count, 30), (
                ros_peer.diagnostic_values(),
                log.read_text(),
            )
    assert publish_until_output(ros_peer, T0 + 100, clean, pose) is not None
    assert process.poll() is None
    text = log.read_text()
    assert text.count("image step 100 is smaller than") == 1, text
    assert text.count("image encoding 'yuv422_weird' is not supported") == 1, text
    assert text.count("image size 320x180 differs from camera_info 640x360") == 1, text


def test_an_image_sent_once_after_the_node_reports_ready_arrives(tmp_path, ros_peer, scenes):
    # A camera's publisher sees the node's subscription before the node's side has matched
    # it, and DDS drops what arrives from a publisher not yet matched: the node reports its
    # side (``image_publishers``, ``camera_info_publishers``) and the feed waits for it. Each
    # round is a node just started, whose first and only image must be counted.
    pose, clean, _, _ = scenes
    image = malformed_images(clean)["step"]  # counted without rendering a reference
    for round_ in range(3):
        namespace = f"ready{round_}"
        feed = CameraFeed(INTRINSICS, namespace=namespace, outputs=("mask",))
        log = tmp_path / f"{namespace}.log"
        process = start_node(
            log,
            "reference_scale:=0.5",
            "diagnostics_period_s:=0.2",
            "max_input_age_s:=0.0",  # the one image must be processed, however slow the machine
            namespace=namespace,
        )
        try:
            assert feed.wait_for_node(60.0), log.read_text()
            feed.publish_frame(T0 + 1, None, pose, SUN, image=image)
            assert feed.wait_for(
                lambda f=feed: int(f.diagnostic_values().get("errors_step", 0)) >= 1, 30
            ), (feed.diagnostic_values(), log.read_text())
            assert feed.diagnostic_values()["frames_received"] == "1"
        finally:
            stop_node(process)
            feed.node.destroy_node()


FULL_HD = CameraIntrinsics(1920, 1080, 1333.33, 1333.33, 960.0, 540.0)


def counter(values, name):
    return int(values.get(name, 0))


def failed_frames(values):
    """Images the node took but could not process, each counted once under its cause."""
    errors = sum(int(v) for k, v in values.items() if k.startswith("errors_"))
    return errors + counter(values, "pose_lookup_failures")


def accounted_for(values):
    """Whether every image the node received was processed, dropped as stale (a newer one
    replaced it before it was taken), skipped before the first camera_info (a start-up
    state: the node's first image may come before its first camera_info) or failed:
    nothing is waiting or in progress."""
    return bool(values) and counter(values, "frames_received") == (
        counter(values, "frames_processed")
        + counter(values, "frames_dropped_stale")
        + counter(values, "frames_before_first_camera_info")
        + failed_frames(values)
    )


def test_every_frame_of_a_full_hd_burst_is_processed_or_counted_as_dropped_and_memory_is_flat(
    node_process, ros_peer, scenes
):
    # Frames arrive at 30 Hz, faster than this machine may process full HD: the node keeps
    # the newest and counts the others as dropped. The check is the accounting, whatever the
    # machine's speed: once the node is idle again, each image it received was processed
    # (and its mask arrived) or dropped, none failed, and the last burst did not grow memory.
    process, log = node_process
    pose = scenes[0]
    with ReferenceRenderer(None, FULL_HD, scale=1.0) as camera:
        clean = camera.render(pose, SUN).rgb
    anomalous = clean.copy()
    anomalous[100:300, 800:1100] = (230, 180, 40)
    node = psutil.Process(process.pid)
    ros_peer.intrinsics = FULL_HD  # the node rebuilds its renderer for the new camera_info

    def idle_counters():
        assert ros_peer.wait_for(lambda: accounted_for(ros_peer.diagnostic_values()), 120.0), (
            ros_peer.diagnostic_values(),
            log.read_text(),
        )
        return ros_peer.diagnostic_values()

    def burst(first_stamp):
        before = idle_counters()
        for index in range(100):
            deadline = time.monotonic() + 1 / 30
            ros_peer.publish_frame(
                first_stamp + index, anomalous if index % 2 else clean, pose, SUN
            )
            # Read what arrives meanwhile: a backlog would overflow the mask's history.
            while (left := deadline - time.monotonic()) > 0:
                rclpy.spin_once(ros_peer.node, timeout_sec=left)

        def masks():
            return sum(1 for s in ros_peer.received["mask"] if first_stamp <= s < first_stamp + 100)

        def done():
            values = ros_peer.diagnostic_values()
            processed = counter(values, "frames_processed") - counter(before, "frames_processed")
            # A frame of an earlier test still in flight when the counters read idle may be
            # received (and processed) during the burst: it has no mask of the burst's.
            received = counter(values, "frames_received") - counter(before, "frames_received")
            strays = max(0, received - 100)
            return accounted_for(values) and masks() <= processed <= masks() + strays

        assert ros_peer.wait_for(done, 120.0), (
            f"before {before}, now {ros_peer.diagnostic_values()}, {masks()} masks"
        )
        after = ros_peer.diagnostic_values()
        assert failed_frames(after) == failed_frames(before), (before, after)
        assert masks() >= 1  # the newest frame the node received is never dropped
        return node.memory_info().rss

    ros_peer.set_outputs(["anomaly"])  # ~/mask and ~/anomaly: the peer keeps up with them
    try:
        rss_first = burst(T0 + 1000)
        rss_second = burst(T0 + 2000)
    finally:
        ros_peer.set_outputs(["score", "overlay", "anomaly"])
        ros_peer.intrinsics = INTRINSICS
    assert process.poll() is None, log.read_text()
    assert rss_second <= 1.10 * rss_first, (rss_first, rss_second)
