"""The processing thread's shutdown and the demo recorder's memory bound (no DDS needed)."""

import array
import inspect
import threading
import time
import types

import numpy as np
import pytest
import rclpy  # noqa: F401 - the worker's diagnostics need rclpy (skipped on the distro route)
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.subscription import Subscription
from sensor_msgs.msg import Image

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.pipeline import ProcessedFrame
from allo_mrad_ros.ros import worker as worker_module
from allo_mrad_ros.ros.buffers import LatestSlot
from allo_mrad_ros.ros.diagnostics import _MAX_LOGGED_KINDS, Diagnostics
from allo_mrad_ros.ros.messages import MessageError, fill_image
from allo_mrad_ros.ros.outputs import result_status
from allo_mrad_ros.ros.parameters import default_config, node_parameters, validate
from allo_mrad_ros.ros.recorder import OutputRecorder, RecorderError, image_score_of
from allo_mrad_ros.ros.worker import ProcessingWorker, Snapshot

CAMERA = CameraIntrinsics(8, 6, 8.0, 8.0, 4.0, 3.0)


class Quiet:
    def __getattr__(self, name):
        return lambda *args, **kwargs: None


class Counting(Quiet):
    def __init__(self):
        self.reports = []
        self.stages = Quiet()

    def report(self, error, detail=""):
        self.reports.append(error)


@pytest.mark.parametrize("pipelined", [True, False])
def test_nothing_is_published_after_stop_returns_even_when_the_join_expires(monkeypatch, pipelined):
    entered, release = threading.Event(), threading.Event()
    views = []

    class SlowPipeline:
        provider = types.SimpleNamespace(
            camera=CAMERA,
            render=lambda view, time_s=None: "reference",
            close=lambda: None,
            reuse=None,
        )

        def close(self):
            pass

        def detect(self, image, reference, score_map=True, view=None):
            views.append(view)  # the view rendered: the detector places the Sun's glare by it
            entered.set()
            release.wait(30)
            result = types.SimpleNamespace(anomalous=False)
            return ProcessedFrame(reference, {"MRAD": result}, {"render": 0.0, "MRAD": 0.0})

    monkeypatch.setattr(
        ProcessingWorker, "_pipeline_for", lambda self, state, p, b: (SlowPipeline(), b)
    )
    published = []
    slot = LatestSlot()
    state = Snapshot(CAMERA, None, np.ones(3), 1.0, ())
    worker = ProcessingWorker(
        slot,
        lambda _msg=None: state,
        lambda msg, s: "view",
        lambda *a: published.append(a),
        Counting(),
        Quiet(),
        pipelined,
    )
    msg = fill_image(Image(), None, np.zeros((6, 8, 3), np.uint8), "rgb8")
    slot.put((msg, 0.0))
    assert entered.wait(30)
    worker.stop(timeout_s=0.1)  # the frame is still in process: the join expires
    assert any(thread.is_alive() for thread in worker._threads)  # still detecting
    release.set()
    worker.join(30)
    assert not any(thread.is_alive() for thread in worker._threads)
    assert published == []
    assert views == ["view"]


@pytest.mark.parametrize("pipelined", [True, False])
def test_the_worker_survives_an_unexpected_exception_and_reports_it(monkeypatch, pipelined):
    calls = []

    def flaky(self, state, pipeline, built_for):
        calls.append(1)
        if len(calls) == 1:
            raise KeyError("a bug")
        return None, built_for

    monkeypatch.setattr(ProcessingWorker, "_pipeline_for", flaky)
    diagnostics = Counting()
    slot = LatestSlot()
    state = Snapshot(CAMERA, None, np.ones(3), 1.0, ())
    worker = ProcessingWorker(
        slot, lambda _msg=None: state, None, None, diagnostics, Quiet(), pipelined
    )
    try:
        slot.put(("not a message", 0.0))
        slot.put(("another", 0.0))
        assert _wait(lambda: len(calls) >= 3)
        assert worker.is_alive()
        assert diagnostics.reports[0].cause == "internal"
        assert "KeyError" in str(diagnostics.reports[0])
    finally:
        worker.stop()


class Told(Counting):
    def __init__(self):
        super().__init__()
        self.counted: list[str] = []
        self.lines: list[tuple[str, str]] = []

    def count(self, name, *args):
        self.counted.append(name)

    def __getattr__(self, level):
        return lambda text, *a, **k: self.lines.append((level, text))


@pytest.mark.parametrize("pipelined", [True, False])
def test_frames_before_the_first_camera_info_are_counted_and_told_once_not_reported(pipelined):
    told = Told()
    problem = MessageError("camera_info", "no valid camera_info")
    waiting = Snapshot(None, None, np.ones(3), 1.0, (), problem, waiting_for_camera_info=True)
    slot = LatestSlot()
    worker = ProcessingWorker(slot, lambda _msg=None: waiting, None, None, told, told, pipelined)
    msg = fill_image(Image(), None, np.zeros((6, 8, 3), np.uint8), "rgb8")
    try:
        for frame in range(1, 4):
            slot.put((msg, 0.0))
            assert _wait(lambda n=frame: told.counted.count("frames_before_first_camera_info") == n)
    finally:
        worker.stop()
    assert told.reports == []  # a start-up state, not an input error
    infos = [text for level, text in told.lines if "first camera_info" in text]
    assert len(infos) == 1 and all(level == "info" for level, text in told.lines if text in infos)


def _wait(condition, timeout=30.0):
    event = threading.Event()
    end = worker_module.time.monotonic() + timeout
    while worker_module.time.monotonic() < end:
        if condition():
            return True
        event.wait(0.02)
    return condition()


class FakeNode:
    def __init__(self):
        self.callbacks = {}

    def create_subscription(self, kind, topic, callback, qos):
        self.callbacks[topic] = callback


def result_at(stamp_ns, image_score):
    msg = DiagnosticArray(status=[result_status("/mrad_detector", False, 0, 4, [], 0.0)])
    for value in msg.status[0].values:
        if value.key == "image_score":
            value.value = image_score
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    return msg


def image_at(stamp_ns, data=None, encoding="mono8"):
    data = np.zeros((2, 2), np.uint8) if data is None else data
    msg = fill_image(Image(), None, data, encoding)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    return msg


def test_recorder_forgets_the_oldest_unmatched_outputs_and_inputs():
    node, frames = FakeNode(), []
    recorder = OutputRecorder(node, frames.append, capacity=50)
    score = node.callbacks["/mrad_detector/score"]
    mask = node.callbacks["/mrad_detector/mask"]
    image = node.callbacks["/arm_camera/image_raw"]
    for stamp in range(1000):
        deliver(image, image_at(stamp))
        score(image_at(stamp, np.zeros((2, 2), np.float32), "32FC1"))
    assert len(recorder._pending) == 50 and len(recorder._input_arrival) == 50
    assert recorder.unmatched == 950
    mask(image_at(999))
    assert frames == []  # the result is still missing
    node.callbacks["/mrad_detector/result"](result_at(999, "12.5"))
    assert len(frames) == 1 and frames[0].stamp_ns == 999 and frames[0].latency_ms is not None
    assert frames[0].image_score == 12.5  # a recent stamp still pairs, with its latency


def deliver(callback, msg, info=None):
    """Call a subscription callback as rclpy does: with the message info where it takes it."""
    try:
        inspect.signature(callback).bind(msg)
    except TypeError:
        return callback(msg, info or {"source_timestamp": 0, "received_timestamp": 0})
    return callback(msg)


def test_the_recorder_s_latency_counts_from_the_input_s_publication_where_rclpy_says_it():
    node, frames = FakeNode(), []
    OutputRecorder(node, frames.append)
    callbacks = node.callbacks
    if not hasattr(Subscription, "CallbackType"):
        pytest.skip("this rclpy (Humble) passes no message info")
    # Published 5 s before this process received it: the latency is at least that.
    sent_ns = time.time_ns() - 5 * 10**9
    deliver(callbacks["/arm_camera/image_raw"], image_at(7), {"source_timestamp": sent_ns})
    callbacks["/mrad_detector/score"](image_at(7, np.zeros((2, 2), np.float32), "32FC1"))
    callbacks["/mrad_detector/mask"](image_at(7))
    callbacks["/mrad_detector/result"](result_at(7, "1.0"))
    assert len(frames) == 1 and frames[0].latency_ms >= 5000.0


def test_the_recorder_keeps_the_node_s_latest_pipeline_status():
    node = FakeNode()
    recorder = OutputRecorder(node, lambda frame: None)
    assert recorder.node_status == {}
    other = DiagnosticStatus(name="other_node: pipeline", values=[KeyValue(key="a", value="1")])
    ours = DiagnosticStatus(
        name="mrad_detector: pipeline",
        values=[KeyValue(key="input_age_published_ms_p50", value="41.5")],
    )
    node.callbacks["/diagnostics"](DiagnosticArray(status=[other, ours]))
    assert recorder.node_status == {"input_age_published_ms_p50": "41.5"}
    node.callbacks["/diagnostics"](DiagnosticArray(status=[other]))  # not ours: kept
    assert recorder.node_status == {"input_age_published_ms_p50": "41.5"}


def test_recorder_takes_the_image_score_from_the_node_result():
    assert image_score_of(result_at(1, "87.125")) == 87.125
    with pytest.raises(RecorderError, match="image_score"):
        image_score_of(result_at(1, "n/a"))
    with pytest.raises(RecorderError, match="image_score"):
        image_score_of(DiagnosticArray())


class LoggingNode:
    """What Diagnostics needs of a node: a publisher, a timer and a logger that keeps lines."""

    def __init__(self):
        self.errors = []

    def create_publisher(self, kind, topic, depth):
        return None

    def create_timer(self, period_s, callback):
        return None

    def get_logger(self):
        return types.SimpleNamespace(error=self.errors.append)

    def get_fully_qualified_name(self):
        return "/mrad_detector"


def test_diagnostics_remembers_a_bounded_number_of_logged_error_kinds():
    """Messages that differ in more than numbers (object addresses, frame names) are new
    kinds: the log stops at the cap, and so must the set of kinds seen."""
    node = LoggingNode()
    diagnostics = Diagnostics(
        node, default_config(), received=lambda: 0, pose_source=lambda: "topic"
    )
    for index in range(3 * _MAX_LOGGED_KINDS):
        name = "".join(chr(ord("a") + int(digit)) for digit in str(index))  # no digits left
        diagnostics.report(MessageError("internal", f"frame failed in camera {name}"))
    assert len(node.errors) == _MAX_LOGGED_KINDS
    assert len(diagnostics._logged_kinds) == _MAX_LOGGED_KINDS
    counted = {kv.key: kv.value for kv in diagnostics.status().values}
    assert counted["errors_internal"] == str(3 * _MAX_LOGGED_KINDS)


@pytest.mark.parametrize(
    "value", [array.array("d", [0.0, 3.0, 4.0]), (0, 3, 4), np.array([0.0, 3.0, 4.0])]
)
def test_sun_direction_accepts_any_sequence_of_three_numbers(value):
    parameter = node_parameters(False)["sun_direction"]
    assert validate("sun_direction", parameter, value) == [0.0, 0.6, 0.8]


@pytest.mark.parametrize(
    ("value", "reason"),
    [
        ([1e300, 1e300, 0.0], None),
        ([1e-320, 0.0, 0.0], None),
        ([0.0, 0.0, 0.0], "zero vector"),
        ([float("inf"), 0.0, 0.0], "finite"),
        ("1,2,3", "list of 3 numbers"),
        ([True, 0.0, 0.0], "list of 3 numbers"),
    ],
)
def test_sun_direction_is_stored_as_a_unit_vector_or_refused(value, reason):
    parameter = node_parameters(False)["sun_direction"]
    if reason is None:
        unit = np.array(validate("sun_direction", parameter, value))
        assert np.isclose(np.linalg.norm(unit), 1.0)
        assert np.allclose(
            unit,
            np.array(value)
            / np.max(np.abs(value))
            / np.linalg.norm(np.array(value) / np.max(np.abs(value))),
        )
    else:
        with pytest.raises(ValueError, match=reason):
            validate("sun_direction", parameter, value)
