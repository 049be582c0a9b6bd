"""Where a frame's time goes: its instants from publication to published outputs, the stages
between them, its age when taken and when published, as /diagnostics reports them.

Instants are given, not measured: the stages are checked against the differences of the
instants a test chose, and the worker runs on stand-in stages, so nothing depends on how
fast the machine is.
"""

import threading
import time
import types

import numpy as np
import pytest
import rclpy  # noqa: F401 - the worker's diagnostics need rclpy (skipped on the distro route)
from diagnostic_msgs.msg import DiagnosticStatus
from sensor_msgs.msg import Image

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.pipeline import ProcessedFrame
from allo_mrad_ros.ros.buffers import LatestSlot
from allo_mrad_ros.ros.diagnostics import Diagnostics
from allo_mrad_ros.ros.inputs import arrival_of
from allo_mrad_ros.ros.messages import MessageError, fill_image
from allo_mrad_ros.ros.parameters import default_config
from allo_mrad_ros.ros.worker import (
    STAGES,
    Arrival,
    ProcessingWorker,
    RenderedFrame,
    Snapshot,
    frame_timings_ms,
)

CAMERA = CameraIntrinsics(8, 6, 8.0, 8.0, 4.0, 3.0)


def rendered_with(arrival, taken, render_start, render_end):
    return RenderedFrame(
        arrival.msg,
        arrival.received,
        None,
        None,
        None,
        0.0,
        arrival,
        taken,
        render_start,
        render_end,
    )


def test_a_frame_s_stages_are_the_gaps_between_its_instants_and_add_up_to_its_age():
    # Published at 10 s, received 10.004, taken 10.010, rendered 10.011-10.031, detected
    # 10.040-10.052, outputs sent by 10.055 (seconds on the monotonic clock).
    arrival = Arrival("msg", received=10.004, published=10.0, arrived=10.001)
    timings = frame_timings_ms(
        rendered_with(arrival, 10.010, 10.011, 10.031), 10.040, 10.052, 10.055
    )
    expected = {
        "middleware": 4.0,
        "slot": 6.0,
        "prepare": 1.0,
        "render": 20.0,
        "handover": 9.0,
        "detect": 12.0,
        "publish": 3.0,
    }
    assert list(timings)[: len(STAGES)] == list(STAGES)
    assert {stage: timings[stage] for stage in STAGES} == pytest.approx(expected)
    assert timings["middleware_queue"] == pytest.approx(3.0)  # of the middleware's 4
    assert timings["age_taken"] == pytest.approx(10.0)
    assert timings["age_published"] == pytest.approx(55.0)
    assert sum(timings[stage] for stage in STAGES) == pytest.approx(timings["age_published"])
    assert timings["receive_to_publish"] == pytest.approx(51.0)


def test_without_its_publication_instant_a_frame_s_age_counts_from_the_callback():
    arrival = Arrival("msg", received=10.004)  # an rclpy that passes no message info
    assert arrival.origin == 10.004
    timings = frame_timings_ms(
        rendered_with(arrival, 10.010, 10.011, 10.031), 10.040, 10.052, 10.055
    )
    assert "middleware" not in timings and "middleware_queue" not in timings
    assert timings["age_taken"] == pytest.approx(6.0)
    assert timings["age_published"] == pytest.approx(51.0)
    # A plain (message, received) tuple, as tests and older callers put, is such an Arrival.
    assert Arrival(*("msg", 3.0)) == Arrival("msg", 3.0, None, None)


def test_the_publication_and_reception_instants_come_from_the_middleware_s_timestamps():
    now_ns = 1_800_000_000_000_000_000  # the system clock when the callback ran
    info = {"source_timestamp": now_ns - 30_000_000, "received_timestamp": now_ns - 2_000_000}
    arrival = arrival_of("msg", 500.0, info, now_ns)
    assert arrival.received == 500.0
    assert arrival.published == pytest.approx(500.0 - 0.030)
    assert arrival.arrived == pytest.approx(500.0 - 0.002)
    # Unknown (0, or no info at all): None. A publisher's clock ahead of this host's: the
    # callback's instant, never a frame younger than its callback.
    assert arrival_of("msg", 500.0, {"source_timestamp": 0, "received_timestamp": 0}, now_ns) == (
        Arrival("msg", 500.0)
    )
    assert arrival_of("msg", 500.0, None, now_ns) == Arrival("msg", 500.0)
    ahead = arrival_of("msg", 500.0, {"source_timestamp": now_ns + 10**9}, now_ns)
    assert ahead.published == 500.0


class StubNode:
    """What Diagnostics needs of a node."""

    def create_publisher(self, kind, topic, depth):
        return None

    def create_timer(self, period_s, callback):
        return None

    def get_logger(self):
        return types.SimpleNamespace(error=lambda line: None, info=lambda line: None)

    def get_fully_qualified_name(self):
        return "/mrad_detector"


class Quiet:
    def __getattr__(self, name):
        return lambda *args, **kwargs: None


def a_worker(monkeypatch, diagnostics, published, pipelined=True, **options):
    """A worker on stand-in render and detect stages, publishing into ``published``."""

    class Pipeline:
        provider = types.SimpleNamespace(
            camera=CAMERA,
            reference_camera=CAMERA,
            render=lambda view, time_s=None: "reference",
            close=lambda: None,
            reuse=None,
        )

        def close(self):
            pass

        def detect(self, image, reference, score_map=True, view=None):
            result = types.SimpleNamespace(anomalous=False)
            return ProcessedFrame(reference, {"MRAD": result}, {"render": 0.0, "MRAD": 0.0})

    monkeypatch.setattr(
        ProcessingWorker, "_pipeline_for", lambda self, state, p, b: (Pipeline(), b)
    )
    slot = LatestSlot()
    state = Snapshot(CAMERA, None, np.ones(3), 1.0, ())
    worker = ProcessingWorker(
        slot,
        lambda _msg=None: state,
        lambda msg, s: "view",
        lambda *a: published.append(a),
        diagnostics,
        Quiet(),
        pipelined,
        **options,
    )
    return slot, worker


def image():
    return fill_image(Image(), None, np.zeros((6, 8, 3), np.uint8), "rgb8")


def wait_for(condition, timeout_s=30.0):
    done = threading.Event()
    for _ in range(int(timeout_s / 0.01)):
        if condition():
            return True
        done.wait(0.01)
    return condition()


def test_the_diagnostics_carry_each_stage_and_the_input_ages_of_the_frames_processed(
    monkeypatch,
):
    diagnostics = Diagnostics(
        StubNode(), default_config(), received=lambda: 1, pose_source=lambda: "topic"
    )
    published = []
    slot, worker = a_worker(monkeypatch, diagnostics, published)
    try:
        received = time.monotonic()
        # Published 2 s before its callback: its age is at least that, on any machine.
        slot.put(Arrival(image(), received, published=received - 2.0, arrived=received - 1.0))
        assert wait_for(lambda: status_values(diagnostics).get("frames_processed") == "1")
    finally:
        worker.stop()
    assert len(published) == 1
    values = status_values(diagnostics)
    for stage in STAGES:
        assert float(values[f"latency_{stage}_ms_p50"]) >= 0.0
        assert f"latency_{stage}_ms_p95" in values
    assert float(values["latency_middleware_ms_p50"]) == pytest.approx(2000.0)
    assert float(values["latency_middleware_queue_ms_p50"]) == pytest.approx(1000.0)
    taken = float(values["input_age_taken_ms_p50"])
    sent = float(values["input_age_published_ms_p95"])
    assert 2000.0 <= taken <= sent


def status_values(diagnostics):
    return {kv.key: kv.value for kv in diagnostics.status().values}


def counter(diagnostics, name):
    return int(status_values(diagnostics).get(name, "0"))


@pytest.mark.parametrize("pipelined", [True, False])
def test_a_frame_older_than_the_bound_when_taken_is_dropped_and_counted_not_processed(
    monkeypatch, pipelined
):
    diagnostics = Diagnostics(
        StubNode(), default_config(), received=lambda: 1, pose_source=lambda: "topic"
    )
    published = []
    # A bound of an hour: a frame published two hours ago is older on any machine, one
    # published now is not.
    slot, worker = a_worker(
        monkeypatch, diagnostics, published, max_input_age_s=lambda: 3600.0, pipelined=pipelined
    )
    try:
        now = time.monotonic()
        stale = image()
        stale.header.stamp.sec = 1
        slot.put(Arrival(stale, now, published=now - 7200.0))
        assert wait_for(lambda: counter(diagnostics, "frames_dropped_too_old") == 1)
        fresh = image()
        fresh.header.stamp.sec = 2
        slot.put(Arrival(fresh, time.monotonic(), published=time.monotonic()))
        assert wait_for(lambda: counter(diagnostics, "frames_processed") == 1)
    finally:
        worker.stop()
    assert [call[0].header.stamp.sec for call in published] == [2]
    assert counter(diagnostics, "frames_dropped_too_old") == 1


def test_a_frame_too_old_that_does_not_fit_its_camera_info_is_reported_for_its_size(
    monkeypatch,
):
    # A camera whose images never fit its camera_info, on a machine slow enough that every
    # frame is too old: the size is what the user must read, not the age.
    diagnostics = Diagnostics(
        StubNode(), default_config(), received=lambda: 1, pose_source=lambda: "topic"
    )
    published = []
    refusal = MessageError("size", "image size 4000x4000 differs from camera_info 320x180")
    slot, worker = a_worker(
        monkeypatch,
        diagnostics,
        published,
        max_input_age_s=lambda: 3600.0,
        size_refusal=lambda msg: refusal if msg.header.stamp.sec == 1 else None,
    )
    try:
        now = time.monotonic()
        wrong = image()
        wrong.header.stamp.sec = 1
        slot.put(Arrival(wrong, now, published=now - 7200.0))
        assert wait_for(lambda: counter(diagnostics, "errors_size") == 1)
        fitting = image()
        fitting.header.stamp.sec = 2
        slot.put(Arrival(fitting, time.monotonic(), published=time.monotonic() - 7200.0))
        assert wait_for(lambda: counter(diagnostics, "frames_dropped_too_old") == 1)
    finally:
        worker.stop()
    assert published == [] and counter(diagnostics, "errors_size") == 1


def test_without_a_bound_no_frame_is_too_old(monkeypatch):
    diagnostics = Diagnostics(
        StubNode(), default_config(), received=lambda: 1, pose_source=lambda: "topic"
    )
    published = []
    slot, worker = a_worker(monkeypatch, diagnostics, published, max_input_age_s=lambda: 0.0)
    try:
        slot.put(Arrival(image(), time.monotonic(), published=time.monotonic() - 7200.0))
        assert wait_for(lambda: counter(diagnostics, "frames_processed") == 1)
    finally:
        worker.stop()
    assert len(published) == 1 and counter(diagnostics, "frames_dropped_too_old") == 0
    assert float(status_values(diagnostics)["input_age_taken_ms_p50"]) >= 7200e3


def test_when_every_frame_is_too_old_the_warning_says_so():
    diagnostics = Diagnostics(
        StubNode(), default_config(), received=lambda: 3, pose_source=lambda: "topic"
    )
    diagnostics.input_seen("camera")
    for _ in range(3):
        diagnostics.count("frames_dropped_too_old")
    status = diagnostics.status()
    assert status.level == DiagnosticStatus.WARN
    assert status.message.endswith("(3 dropped as older than max_input_age_s)")
