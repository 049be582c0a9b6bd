"""ROS perception conventions of the node, checked without DDS where possible.

TF frame ids, the result's hardware_id, camera_info binning/ROI and pairing by stamp,
encodings a camera driver sends, vision_msgs detections (a stand-in of the message
definitions: no vision_msgs wheel exists), diagnostics as diagnostic_updater reports them.
"""

from __future__ import annotations

import sys
import types
from dataclasses import dataclass, field, replace

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector.pipeline import DetectionResult
from allo_mrad_ros.detector.regions import extract_regions, region_score
from allo_mrad_ros.pipeline import ProcessedFrame
from allo_mrad_ros.ros import messages
from allo_mrad_ros.ros.diagnostics import Diagnostics
from allo_mrad_ros.ros.messages import MessageError
from allo_mrad_ros.ros.node import MradDetectorNode, camera_info_topic
from allo_mrad_ros.ros.outputs import detection_array, result_status
from allo_mrad_ros.ros.parameters import default_config
from allo_mrad_ros.ros.pose_source import PoseSource

pytestmark = pytest.mark.ros

CAMERA = CameraIntrinsics(640, 480, 500.0, 500.0, 320.0, 240.0)


@pytest.fixture
def ros():
    rclpy.init()
    yield
    rclpy.shutdown()


# --- TF frame ids --------------------------------------------------------------------------


class _StandInTf(types.ModuleType):
    class TransformException(Exception):
        pass

    class LookupException(TransformException):
        pass

    class ConnectivityException(TransformException):
        pass

    class ExtrapolationException(TransformException):
        pass

    class InvalidArgumentException(TransformException):
        pass

    def __init__(self) -> None:
        super().__init__("tf2_ros")
        module = self

        class Buffer:
            def lookup_transform(self, target, source, time, timeout):
                raise module.InvalidArgumentException(f"invalid frame {source!r}")

        self.Buffer = Buffer
        self.TransformListener = lambda buffer, node: None


@pytest.mark.parametrize("frame_id", ["", "/arm_camera_optical_frame"])
def test_an_empty_or_slash_prefixed_frame_id_in_tf_mode_is_a_counted_message_error(
    ros, monkeypatch, frame_id
):
    monkeypatch.setitem(sys.modules, "tf2_ros", _StandInTf())
    node = rclpy.create_node("tf_frames_test")
    try:
        source = PoseSource(node, "tf", "station", "", QoSProfile(depth=5), lambda e: None)
        with pytest.raises(MessageError) as caught:
            source.lookup(Header(frame_id=frame_id), 0.05, 0.0)
        assert caught.value.cause == "frame_id" and "frame skipped" in str(caught.value)
        # Any other tf2 exception is a failed lookup (None, counted by the node), not a crash.
        assert source.lookup(Header(frame_id="bad frame"), 0.05, 0.0) is None
    finally:
        node.destroy_node()


# --- result hardware_id ----------------------------------------------------------------------


def test_the_result_names_the_hardware_id_given():
    status = result_status("mrad_detector", False, 0, 10, [], 0.0, "arm_camera_left")
    assert status.hardware_id == "arm_camera_left"
    assert result_status("mrad_detector", False, 0, 10, [], 0.0).hardware_id


def test_the_node_passes_its_hardware_id_parameter_to_the_result(ros):
    node = MradDetectorNode(
        parameter_overrides=[
            Parameter("pose_source", value="topic"),
            Parameter("max_input_age_s", value=0.0),  # slow machines: no frame dropped for age
            Parameter("hardware_id", value="cam7"),
        ]
    )
    try:
        sent: list = []
        node._outputs.result = types.SimpleNamespace(
            get_subscription_count=lambda: 1, publish=sent.append
        )
        mask = np.zeros((4, 6), np.uint8)
        result = DetectionResult(
            work_score=np.zeros((4, 6), np.float32),
            raw_score=np.zeros((4, 6), np.float32),
            mask=mask,
            area=0,
            anomalous=False,
            image_score=0.0,
            regions=extract_regions(mask, np.zeros((4, 6), np.float32), (4, 6), 8),
        )
        frame = ProcessedFrame(reference=np.zeros((2, 3, 3), np.uint8), results={"MRAD": result})
        msg = Image(header=Header(frame_id="camera_optical"))
        node._publish(msg, np.zeros((4, 6, 3), np.uint8), frame)
        (array,) = sent
        assert array.status[0].hardware_id == "cam7"  # the parameter, not the image's frame
    finally:
        node.destroy_node()


# --- camera_info binning, ROI, pairing -------------------------------------------------------


def _info(**fields) -> CameraInfo:
    info = messages.fill_camera_info(CameraInfo(), CAMERA, "cam_optical_frame")
    for key, value in fields.items():
        setattr(info, key, value)
    return info


def test_binning_divides_the_camera_as_image_geometry_does():
    info = _info(binning_x=2, binning_y=4)
    camera = messages.camera_intrinsics(info, rectified=False)
    assert camera == CameraIntrinsics(320, 120, 250.0, 125.0, 160.0, 60.0)


def test_an_roi_crops_the_camera_as_image_geometry_does():
    info = _info()
    info.roi.x_offset, info.roi.y_offset, info.roi.width, info.roi.height = 100, 40, 200, 100
    camera = messages.camera_intrinsics(info, rectified=False)
    assert camera == CameraIntrinsics(200, 100, 500.0, 500.0, 220.0, 200.0)
    info.binning_x = info.binning_y = 2
    assert messages.camera_intrinsics(info, rectified=True) == CameraIntrinsics(
        100, 50, 250.0, 250.0, 110.0, 100.0
    )


def test_an_roi_outside_the_image_or_on_a_distorted_rectified_camera_is_refused():
    info = _info()
    info.roi.x_offset, info.roi.width, info.roi.height = 600, 100, 100
    with pytest.raises(MessageError, match="outside"):
        messages.camera_intrinsics(info, rectified=False)
    info = _info(d=[0.1, 0.0, 0.0, 0.0, 0.0])
    info.roi.width, info.roi.height = 100, 100
    with pytest.raises(MessageError, match="ROI and distortion"):
        messages.camera_intrinsics(info, rectified=True)


def test_camera_info_follows_the_image_topic():
    assert camera_info_topic("/arm_camera/image_raw") == "/arm_camera/camera_info"
    assert camera_info_topic("/cam/left/image_rect") == "/cam/left/camera_info"


def _image(stamp_ns: int, frame_id: str) -> Image:
    msg = Image()
    msg.header.frame_id = frame_id
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    return msg


def test_an_image_is_paired_with_the_camera_info_of_its_stamp_and_frame_mismatches_count(ros):
    node = MradDetectorNode(
        parameter_overrides=[
            Parameter("pose_source", value="topic"),
            Parameter("max_input_age_s", value=0.0),  # slow machines: no frame dropped for age
            Parameter("camera_info_tolerance_s", value=0.001),
        ]
    )
    try:
        assert node._info_topic == "/arm_camera/camera_info"
        small = messages.fill_camera_info(CameraInfo(), CAMERA.scaled(0.5), "cam_optical_frame")
        large = messages.fill_camera_info(CameraInfo(), CAMERA, "other_frame")
        small.header.stamp.sec, large.header.stamp.sec = 10, 11
        before = node._inputs.snapshot(_image(9 * 10**9, "cam_optical_frame"))
        assert before.intrinsics is None and before.waiting_for_camera_info  # start-up
        node._inputs.on_camera_info(small)
        node._inputs.on_camera_info(large)  # the latest, but not the first image's
        state = node._inputs.snapshot(_image(10 * 10**9 + 500_000, "cam_optical_frame"))
        assert state.camera_problem is None and state.intrinsics == CAMERA.scaled(0.5)
        assert node._diagnostics.status().values  # no mismatch counted yet
        counted = {kv.key: kv.value for kv in node._diagnostics.status().values}
        assert "camera_info_frame_mismatches" not in counted
        state = node._inputs.snapshot(_image(11 * 10**9, "cam_optical_frame"))
        assert state.intrinsics == CAMERA
        counted = {kv.key: kv.value for kv in node._diagnostics.status().values}
        assert counted["camera_info_frame_mismatches"] == "1"
        unpaired = node._inputs.snapshot(_image(12 * 10**9, "cam_optical_frame"))
        assert unpaired.intrinsics is None and "no valid camera_info" in str(
            unpaired.camera_problem
        )
        assert not unpaired.waiting_for_camera_info  # camera_infos came, none of its stamp
    finally:
        node.destroy_node()


# --- encodings ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("encoding", "order"),
    [("bgr16", [2, 1, 0]), ("rgb16", [0, 1, 2]), ("rgba16", [0, 1, 2]), ("bgra16", [2, 1, 0])],
)
@pytest.mark.parametrize("big_endian", [0, 1])
def test_16_bit_colour_encodings_decode_to_rgb(encoding, order, big_endian):
    rgb = np.arange(2 * 3 * 3, dtype=np.uint16).reshape(2, 3, 3) * 1000
    channels = rgb[..., order]
    if encoding.endswith("a16"):
        channels = np.dstack([channels, np.full(rgb.shape[:2], 7, np.uint16)])
    data = channels.astype(">u2" if big_endian else "<u2").tobytes()
    msg = Image(height=2, width=3, encoding=encoding, is_bigendian=big_endian)
    msg.step = 3 * channels.shape[2] * 2
    msg.data = data
    assert np.array_equal(messages.image_to_rgb(msg), rgb)


@pytest.mark.parametrize("encoding", ["bayer_rggb8", "bayer_gbrg16", "yuv422", "yuv422_yuy2"])
def test_raw_sensor_encodings_name_the_debayering_node(encoding):
    msg = Image(height=2, width=2, encoding=encoding, step=4)
    msg.data = bytes(8)
    with pytest.raises(MessageError, match="image_proc's debayer node"):
        messages.image_to_rgb(msg)


# --- detections (stand-in of vision_msgs' definitions) -------------------------------------


@dataclass
class _Point2D:  # vision_msgs/Point2D
    x: float = 0.0
    y: float = 0.0


@dataclass
class _Pose2D:  # vision_msgs/Pose2D (Humble and later)
    position: _Point2D = field(default_factory=_Point2D)
    theta: float = 0.0


@dataclass
class _BoundingBox2D:  # vision_msgs/BoundingBox2D
    center: _Pose2D = field(default_factory=_Pose2D)
    size_x: float = 0.0
    size_y: float = 0.0


@dataclass
class _ObjectHypothesis:  # vision_msgs/ObjectHypothesis
    class_id: str = ""
    score: float = 0.0


@dataclass
class _ObjectHypothesisWithPose:  # vision_msgs/ObjectHypothesisWithPose (pose left default)
    hypothesis: _ObjectHypothesis = field(default_factory=_ObjectHypothesis)
    pose: object = None


@dataclass
class _Detection2D:  # vision_msgs/Detection2D
    header: object = None
    results: list = field(default_factory=list)
    bbox: _BoundingBox2D = field(default_factory=_BoundingBox2D)
    id: str = ""


@dataclass
class _Detection2DArray:  # vision_msgs/Detection2DArray
    header: object = None
    detections: list = field(default_factory=list)


STAND_IN_VISION_MSGS = types.SimpleNamespace(
    Detection2DArray=_Detection2DArray,
    Detection2D=_Detection2D,
    ObjectHypothesisWithPose=_ObjectHypothesisWithPose,
)


@pytest.mark.parametrize("connectivity", [4, 8])
def test_detections_carry_one_box_and_anomaly_hypothesis_per_region(connectivity):
    mask = np.zeros((20, 30), np.uint8)
    mask[2:6, 3:9] = 255
    mask[10:20, 20:25] = 255
    mask[6, 9] = 255  # touches the first region at a corner: joins it 8-connected only
    evidence = np.zeros((20, 30), np.float32)
    evidence[4, 5] = 80.0
    evidence[15, 22] = 200.0
    evidence[6, 9] = 30.0
    header = Header(frame_id="cam_optical_frame")
    regions = extract_regions(mask, evidence, mask.shape, connectivity)
    array = detection_array(STAND_IN_VISION_MSGS, header, regions)
    assert array.header is header and len(array.detections) == len(regions)
    first, *middle, last = array.detections
    assert first.header is header
    width, height = (6, 4) if connectivity == 4 else (7, 5)
    centre = first.bbox.center.position
    assert (centre.x, centre.y) == (3 + width / 2, 2 + height / 2)
    assert (first.bbox.size_x, first.bbox.size_y) == (width, height)
    (hypothesis,) = first.results
    # vision_msgs' score lies in [0, 1]: the region's calibrated score, the share of the
    # shipped table's normal-region peaks below its peak evidence.
    assert hypothesis.hypothesis.class_id == "anomaly"
    assert hypothesis.hypothesis.score == region_score(80.0)
    assert last.results[0].hypothesis.score == region_score(200.0)
    assert 0.0 <= hypothesis.hypothesis.score <= last.results[0].hypothesis.score <= 1.0
    assert (last.bbox.size_x, last.bbox.size_y) == (5.0, 10.0)
    assert [d.results[0].hypothesis.score for d in middle] == (
        [region_score(30.0)] if connectivity == 4 else []
    )


# --- diagnostics ---------------------------------------------------------------------------


def test_idle_with_nobody_subscribed_is_ok_with_its_reason_and_never_stale(ros):
    node = rclpy.create_node("diagnostics_idle_test")
    try:
        config = replace(default_config(), input_timeout_s=0.1)
        diagnostics = Diagnostics(
            node,
            config,
            received=lambda: 10,
            pose_source=lambda: "topic",
            idle=lambda: "no subscriber to any output: inputs unsubscribed",
            inputs_subscribed=lambda: False,
        )
        diagnostics.input_seen("cam", 5, 5)
        status = diagnostics.status()
        assert status.level == DiagnosticStatus.OK and status.message.startswith("idle: ")
        values = {kv.key: kv.value for kv in status.values}
        assert values["inputs_subscribed"] == "false" and values["pose_source"] == "topic"
        silent = Diagnostics(node, config, received=lambda: 0, pose_source=lambda: "topic")
        assert silent.status().level == DiagnosticStatus.ERROR  # no image at all: not STALE
    finally:
        node.destroy_node()


def test_rate_and_stamp_statuses_report_as_diagnostic_updater_does(ros):
    node = rclpy.create_node("diagnostics_rate_test")
    try:
        config = replace(default_config(), expected_rate_hz=30.0, max_stamp_delay_s=0.5)
        diagnostics = Diagnostics(node, config, received=lambda: 0, pose_source=lambda: "topic")
        _pipeline, rate, stamp = diagnostics.statuses()
        assert rate.name.endswith(": input rate") and stamp.name.endswith(": input stamp")
        assert rate.level == DiagnosticStatus.ERROR and rate.message == "No events recorded."
        assert stamp.level == DiagnosticStatus.WARN
        values = {kv.key: kv.value for kv in rate.values}
        assert values["Target frequency (Hz)"] == "30"
        assert values["Minimum acceptable frequency (Hz)"] == "27"
        assert "Duration of window (s)" in values and "Events in window" in values
        diagnostics.input_seen("cam", 10**9, 10**9 + 2 * 10**9)  # 2 s old
        _, rate, stamp = diagnostics.statuses()
        assert rate.level == DiagnosticStatus.WARN and rate.message == "Frequency too low."
        assert stamp.level == DiagnosticStatus.ERROR
        values = {kv.key: kv.value for kv in stamp.values}
        assert values["Latest timestamp delay:"] == "2.000000"
        assert values["Late diagnostic update count:"] == "1"
        assert all(s.level != DiagnosticStatus.STALE for s in diagnostics.statuses())
    finally:
        node.destroy_node()


# --- inputs only while an output is subscribed (over DDS on loopback) --------------------


def test_inputs_are_subscribed_only_while_an_output_has_a_subscriber(ros):
    import threading
    import time

    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped, Vector3Stamped
    from rclpy.executors import SingleThreadedExecutor

    node = MradDetectorNode(
        parameter_overrides=[
            Parameter("pose_source", value="topic"),
            Parameter("max_input_age_s", value=0.0),  # slow machines: no frame dropped for age
            Parameter("diagnostics_period_s", value=0.2),
        ]
    )
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    peer = rclpy.create_node("lazy_inputs_peer")
    statuses: list = []
    peer.create_subscription(
        DiagnosticArray,
        "/diagnostics",
        lambda m: statuses.append(m.status[0]) if m.status[0].name.startswith("mrad") else None,
        10,
    )
    images = peer.create_publisher(Image, "/arm_camera/image_raw", 1)
    infos = peer.create_publisher(CameraInfo, "/arm_camera/camera_info", 1)
    poses = peer.create_publisher(PoseStamped, "/arm_camera/pose", 1)
    suns = peer.create_publisher(Vector3Stamped, "/allo/sun_direction", 1)
    inputs = (images, infos, poses, suns)

    def wait_for(condition, timeout=60.0) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end and not condition():
            rclpy.spin_once(peer, timeout_sec=0.05)
        return condition()

    try:
        assert wait_for(lambda: statuses and statuses[-1].message.startswith("idle"))
        assert wait_for(lambda: all(p.get_subscription_count() == 0 for p in inputs))
        assert statuses[-1].level == DiagnosticStatus.OK
        mask = peer.create_subscription(Image, "/mrad_detector/mask", lambda m: None, 1)
        assert wait_for(lambda: all(p.get_subscription_count() == 1 for p in inputs))
        assert wait_for(lambda: statuses and not statuses[-1].message.startswith("idle"))
        peer.destroy_subscription(mask)
        assert wait_for(lambda: all(p.get_subscription_count() == 0 for p in inputs))
    finally:
        executor.shutdown()
        node.destroy_node()
        peer.destroy_node()


def test_the_camera_frame_follows_the_optical_frame_convention():
    from allo_mrad_ros import interface

    assert f"{interface.HARDWARE_ID}_optical_frame" == interface.CAMERA_FRAME
