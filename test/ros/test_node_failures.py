"""Bad input and faults against the node, over DDS on loopback.

The node runs in this process (so a test can inject a fault into its processing thread) on an
executor thread of its own; a :class:`CameraFeed` peer talks to it over DDS. Every wait is
for a condition with a generous timeout: the test machine is shared and loaded.
"""

import threading
import time

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import Vector3Stamped
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from allo_mrad_ros import interface
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.ros.node import MradDetectorNode
from harness.feed import CameraFeed

pytestmark = pytest.mark.ros

INTRINSICS = CameraIntrinsics(320, 180, 222.2, 222.2, 160.0, 90.0)
POSE = look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0])
IMAGE = np.full((180, 320, 3), 40, np.uint8)
T0 = 1_900_000_000 * 10**9
TIMEOUT = 60.0


@pytest.fixture(scope="module")
def live():
    rclpy.init()
    node = MradDetectorNode(
        parameter_overrides=[
            Parameter("pose_source", value="topic"),
            Parameter("diagnostics_period_s", value=0.2),
            Parameter("input_timeout_s", value=1.0),
            Parameter("reference_scale", value=0.25),
            # Each frame must reach the stage that fails: none dropped for age when slow.
            Parameter("max_input_age_s", value=0.0),
        ]
    )
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    feed = CameraFeed(INTRINSICS)
    assert feed.wait_for_node(TIMEOUT)
    yield node, feed
    executor.shutdown()
    node.destroy_node()
    feed.node.destroy_node()
    rclpy.shutdown()


class Stamps:
    """Fresh stamps for each frame of the module."""

    next = T0

    @classmethod
    def take(cls) -> int:
        cls.next += 10**6
        return cls.next


def process_one(feed, pose=POSE, timeout=TIMEOUT):
    """Publish frames (new stamps) until one comes back processed; return its stamp."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        stamp = Stamps.take()
        feed.publish_frame(stamp, IMAGE, pose)
        if feed.wait_for(lambda s=stamp: s in feed.received["mask"], 1.0):
            return stamp
    return None


def latest_status(feed) -> DiagnosticStatus | None:
    return feed.diagnostics[-1].status[0] if feed.diagnostics else None


# How often frames go out while a test waits: a camera's rate. Polling publishes at
# whatever rate the machine spins, hundreds per second when idle, which overflows the
# node's camera_info queue so that images lose their camera_info and the level never
# settles.
FRAME_PERIOD_S = 0.05


def wait_for_level(feed, level, timeout=TIMEOUT, keep_publishing=False, message=""):
    """Wait for a status of ``level`` whose message holds ``message``: a status of that
    level for another reason (made before what the test waits for) may still be the latest."""
    last = [-FRAME_PERIOD_S]

    def reached():
        if keep_publishing and time.monotonic() - last[0] >= FRAME_PERIOD_S:
            last[0] = time.monotonic()
            feed.publish_frame(Stamps.take(), IMAGE, POSE)
        status = latest_status(feed)
        return status is not None and status.level == level and message in status.message

    return feed.wait_for(reached, timeout)


def set_parameter(feed, name, value: ParameterValue):
    client = feed.node.create_client(SetParameters, "/mrad_detector/set_parameters")
    try:
        assert client.wait_for_service(timeout_sec=TIMEOUT)
        future = client.call_async(
            SetParameters.Request(parameters=[ParameterMsg(name=name, value=value)])
        )
        assert feed.wait_for(future.done, TIMEOUT)
        return future.result().results[0]
    finally:
        feed.node.destroy_client(client)


def double_array(values) -> ParameterValue:
    return ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=values)


def test_a_frame_is_processed_and_diagnostics_are_ok_with_the_images_frame(live):
    _node, feed = live
    assert process_one(feed) is not None
    assert wait_for_level(feed, DiagnosticStatus.OK, keep_publishing=True)
    assert latest_status(feed).hardware_id == "arm_camera_optical_frame"


def test_sun_direction_set_over_the_parameter_service_is_applied(live):
    # rclpy hands the service's double array to the node as array.array.
    node, feed = live
    result = set_parameter(feed, "sun_direction", double_array([0.0, 2.0, 0.0]))
    assert result.successful, result.reason
    assert node._config.sun_direction == (0.0, 1.0, 0.0)
    assert process_one(feed) is not None


def test_huge_sun_vector_keeps_its_direction_and_frames_keep_flowing(live):
    node, feed = live
    result = set_parameter(feed, "sun_direction", double_array([1e300, 1e300, 0.0]))
    assert result.successful, result.reason
    assert np.allclose(node._config.sun_direction, (2**-0.5, 2**-0.5, 0.0))
    sun = Vector3Stamped()
    sun.vector.x, sun.vector.y, sun.vector.z = 1e300, -1e300, 1e300
    sun.header.stamp.sec = T0 // 10**9
    sun.header.frame_id = interface.STATION_FRAME
    feed.pub_sun.publish(sun)
    expected = np.array([1.0, -1.0, 1.0]) / 3**0.5
    assert feed.wait_for(lambda: np.allclose(node._inputs.sun_direction, expected), TIMEOUT)
    stamp = process_one(feed)
    assert stamp is not None
    assert np.isclose(np.linalg.norm(node._inputs.sun_direction), 1.0)
    zero = set_parameter(feed, "sun_direction", double_array([0.0, 0.0, 0.0]))
    assert not zero.successful and "zero vector" in zero.reason
    assert np.allclose(node._config.sun_direction, (2**-0.5, 2**-0.5, 0.0))


def test_absurd_camera_info_is_rejected_once_with_the_limit_and_no_renderer_retries(live, capfd):
    _node, feed = live
    info = feed.camera_info()
    info.width = 2**32 - 1
    for _ in range(5):
        feed.pub_info.publish(info)
        feed.spin(0.3)
    assert feed.wait_for(
        lambda: int(feed.diagnostic_values().get("errors_camera_info", 0)) >= 3, TIMEOUT
    )
    log = capfd.readouterr().err
    assert log.count("4294967295x180 is impossible: at most 16384 pixels per side") == 1, log
    assert "cannot build the renderer" not in log and "libosmesa" not in log
    assert "errors_renderer" not in feed.diagnostic_values()
    assert process_one(feed) is not None  # the good camera_info of the next frames still works


def test_any_exception_in_one_frame_is_logged_with_its_stamp_and_processing_goes_on(live, capfd):
    node, feed = live
    worker = node._worker
    view_of = worker._view_of
    failing = set()

    class InvalidArgumentException(Exception):  # what tf2 raises for a '/'-prefixed frame id
        pass

    def fail_once(msg, state):
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        if not failing:
            failing.add(stamp)
            raise InvalidArgumentException("frame id '/arm_camera' starts with '/'")
        return view_of(msg, state)

    worker._view_of = fail_once
    try:
        assert process_one(feed) is not None
    finally:
        worker._view_of = view_of
    assert worker.is_alive()
    (stamp,) = failing
    log = capfd.readouterr().err
    assert f"frame {stamp} ns failed: InvalidArgumentException" in log, log
    assert feed.wait_for(
        lambda: int(feed.diagnostic_values().get("errors_internal", 0)) >= 1, TIMEOUT
    )


def test_a_different_second_failure_of_one_cause_is_logged_too(live, capfd):
    node, feed = live
    pipeline_error = [ValueError("first reason"), ValueError("quite another reason")]
    view_of = node._worker._view_of

    def fail_twice(msg, state):
        if pipeline_error:
            raise pipeline_error.pop(0)
        return view_of(msg, state)

    node._worker._view_of = fail_twice
    try:
        assert process_one(feed) is not None
    finally:
        node._worker._view_of = view_of
    log = capfd.readouterr().err
    assert "frame rejected: first reason" in log and "frame rejected: quite another reason" in log


def test_a_pose_miss_warns_only_while_it_is_recent(live):
    _node, feed = live
    assert wait_for_level(feed, DiagnosticStatus.OK, keep_publishing=True)
    misses = int(feed.diagnostic_values().get("pose_lookup_failures", 0))
    feed.publish_frame(Stamps.take() + 5 * 10**9, IMAGE, None)  # no pose near this stamp
    assert feed.wait_for(
        lambda: int(feed.diagnostic_values().get("pose_lookup_failures", 0)) > misses, TIMEOUT
    )
    assert wait_for_level(feed, DiagnosticStatus.WARN, keep_publishing=True)
    # Good frames for longer than the window: back to OK, the total stays in the values.
    assert wait_for_level(feed, DiagnosticStatus.OK, keep_publishing=True)
    assert int(feed.diagnostic_values()["pose_lookup_failures"]) > misses


def test_diagnostics_say_error_not_stale_when_images_stop(live):
    # STALE is the diagnostic aggregator's call; the node says ERROR (FrequencyStatus' rule).
    node, feed = live
    assert wait_for_level(feed, DiagnosticStatus.OK, keep_publishing=True)
    stopped = time.monotonic()
    assert wait_for_level(feed, DiagnosticStatus.ERROR)
    waited = time.monotonic() - stopped
    assert "no image on /arm_camera/image_raw" in latest_status(feed).message, waited
    assert node._worker.is_alive()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_diagnostics_say_error_when_the_processing_thread_dies(live, capfd):
    # Last in this module: it kills the worker.
    node, feed = live
    assert wait_for_level(feed, DiagnosticStatus.OK, keep_publishing=True)

    def die(*_args):
        raise SystemExit("injected fault: the processing thread ends")

    node._worker._snapshot = die
    assert feed.wait_for(lambda: not node._worker.is_alive(), TIMEOUT)
    # Made before the thread died, the latest status may say ERROR for the images that
    # stopped meanwhile (a slow machine): the one awaited names the thread.
    stopped = "processing thread stopped"
    assert wait_for_level(feed, DiagnosticStatus.ERROR, keep_publishing=True, message=stopped)
    assert stopped in latest_status(feed).message
    assert "processing thread stopped" in capfd.readouterr().err
