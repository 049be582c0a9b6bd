"""The two-stage processing worker with stand-in render and detect stages (no DDS, no GL).

The stand-ins sleep instead of computing, so the overlap of the stages shows in wall time
whatever the machine's load, and they record which thread called them.
"""

import threading
import time
import types

import numpy as np
import pytest
import rclpy  # noqa: F401 - the worker's diagnostics need rclpy (skipped on the distro route)
from sensor_msgs.msg import Image

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.pipeline import ProcessedFrame
from allo_mrad_ros.ros import worker as worker_module
from allo_mrad_ros.ros.buffers import HandOver, LatestSlot
from allo_mrad_ros.ros.messages import fill_image, stamp_to_ns
from allo_mrad_ros.ros.parameters import detector_parameters, node_config_from, node_parameters
from allo_mrad_ros.ros.worker import ProcessingWorker, Snapshot

CAMERA = CameraIntrinsics(8, 6, 8.0, 8.0, 4.0, 3.0)
OTHER_CAMERA = CameraIntrinsics(16, 12, 16.0, 16.0, 8.0, 6.0)
CONFIG = node_config_from(
    {name: p.default for name, p in {**node_parameters(False), **detector_parameters()}.items()}
)


class Quiet:
    def __getattr__(self, name):
        return lambda *args, **kwargs: None


class Recording(Quiet):
    """Diagnostics and logger stand-in: keeps reports, counters and fatal lines."""

    def __init__(self):
        self.reports, self.counts, self.fatal_lines = [], {}, []
        self.stages = Quiet()

    def report(self, error, detail=""):
        self.reports.append(error)

    def count(self, name):
        self.counts[name] = self.counts.get(name, 0) + 1

    def fatal(self, line):
        self.fatal_lines.append(line)


class Stages:
    """Stand-in render and detect: sleep, record the calling thread, optionally block."""

    def __init__(self, render_s=0.0, detect_s=0.0):
        self.render_s, self.detect_s = render_s, detect_s
        self.gl_threads, self.detect_threads = [], []
        self.built, self.closed, self.score_maps, self.warmed_up = [], [], [], []
        self.gate = threading.Event()
        self.gate.set()
        self.detecting = threading.Event()

    def install(self, monkeypatch):
        stages = self

        class Provider:
            def __init__(self, mesh, camera, settings):
                stages.gl_threads.append(threading.get_ident())
                stages.built.append(camera)
                self.camera, self.settings = camera, settings
                self.reference_camera, self.reuse = camera, None
                self.renderer = types.SimpleNamespace(backend="fake", triangle_count=0)

            def render(self, view, time_s=None):
                stages.gl_threads.append(threading.get_ident())
                time.sleep(seconds(stages.render_s))
                return np.zeros((self.camera.height, self.camera.width, 3), np.uint8)

            def close(self):
                stages.gl_threads.append(threading.get_ident())
                stages.closed.append(self.camera)

        class Pipeline:
            def __init__(self, provider, config):
                self.provider, self.config = provider, config

            @classmethod
            def open(cls, camera, *, mesh, config):
                return cls(Provider(mesh, camera, config.render), config)

            def close(self):
                self.provider.close()

            def with_config(self, config):
                return Pipeline(self.provider, config)

            def warm_up(self):
                stages.warmed_up.append(threading.get_ident())

            def detect(self, image, reference, score_map=True):
                stages.detect_threads.append(threading.get_ident())
                stages.score_maps.append(score_map)
                stages.detecting.set()
                stages.gate.wait(30)
                time.sleep(seconds(stages.detect_s))
                result = types.SimpleNamespace(anomalous=False)
                return ProcessedFrame(reference, {"MRAD": result}, {"render": 0.0, "MRAD": 0.0})

        monkeypatch.setattr(worker_module, "Pipeline", Pipeline)


def seconds(duration):
    return duration() if callable(duration) else duration


def image_at(stamp_ns, camera=CAMERA):
    msg = fill_image(Image(), None, np.zeros((camera.height, camera.width, 3), np.uint8), "rgb8")
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    return msg


class Run:
    """A worker on stand-in stages, fed by the test; records what it publishes and when."""

    def __init__(self, pipelined, camera=CAMERA, score_wanted=lambda: True):
        self.slot = LatestSlot()
        self.score_maps = []  # what publish was told, per frame
        self.camera = camera
        self.diagnostics = Recording()
        self.logger = Recording()
        self.published = []  # (stamp ns, monotonic publish time)
        self.worker = ProcessingWorker(
            self.slot,
            lambda _msg=None: Snapshot(self.camera, CONFIG, np.ones(3), 1.0, ()),
            lambda msg, state: "view",
            lambda msg, image, frame, score_map: (
                self.published.append((stamp_to_ns(msg.header.stamp), time.monotonic()))
                or self.score_maps.append(score_map)
            ),
            self.diagnostics,
            self.logger,
            pipelined,
            score_wanted,
        )

    def put(self, stamp_ns):
        """Offer an image; True if it replaced one never taken (the node counts those)."""
        return self.slot.put((image_at(stamp_ns, self.camera), time.monotonic()))

    def feed_until(self, count, period_s=0.002, timeout_s=60.0):
        """Offer a new image every ``period_s`` until ``count`` are published; their stamps
        are their monotonic offer times in ns."""
        end = time.monotonic() + timeout_s
        while len(self.published) < count and time.monotonic() < end:
            self.put(time.monotonic_ns())
            time.sleep(period_s)
        assert len(self.published) >= count, self.diagnostics.reports


def wait_until(condition, timeout_s=30.0):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(0.005)
    return condition()


@pytest.mark.parametrize("pipelined", [True, False])
def test_results_are_published_in_stamp_order_with_stages_of_varying_length(monkeypatch, pipelined):
    stages = Stages()
    stages.install(monkeypatch)
    # Each call takes another time, so the stages finish in shifting phase.
    durations = iter(np.random.default_rng(0).uniform(0.0, 0.02, 1000))
    stages.render_s = stages.detect_s = lambda: next(durations)
    run = Run(pipelined)
    try:
        run.feed_until(25)
    finally:
        run.worker.stop()
    stamps = [stamp for stamp, _ in run.published]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)
    assert run.diagnostics.reports == []


@pytest.mark.parametrize("pipelined", [True, False])
def test_the_newest_image_wins_and_every_other_one_is_dropped_and_counted(monkeypatch, pipelined):
    stages = Stages()
    stages.install(monkeypatch)
    stages.gate.clear()  # the first frame stays in detection
    run = Run(pipelined)
    try:
        dropped = int(run.put(1))
        assert stages.detecting.wait(30)
        for stamp in range(2, 11):
            dropped += int(run.put(stamp))
            time.sleep(0.01)
        stages.gate.set()
        assert wait_until(lambda: run.published and run.published[-1][0] == 10)
        time.sleep(0.1)
    finally:
        run.worker.stop()
    stamps = [stamp for stamp, _ in run.published]
    # One frame may already be rendered while the first is detected; nothing else between.
    assert stamps[0] == 1 and stamps[-1] == 10 and len(stamps) <= (3 if pipelined else 2)
    assert dropped == 10 - len(stamps) == run.slot.dropped


def test_the_two_stages_overlap_so_a_frame_costs_the_slower_stage_not_the_sum(monkeypatch):
    stage_s, frames = 0.04, 10
    per_frame = {}
    for pipelined in (False, True):
        stages = Stages(render_s=stage_s, detect_s=stage_s)
        stages.install(monkeypatch)
        run = Run(pipelined)
        try:
            run.feed_until(frames + 1)
        finally:
            run.worker.stop()
        times = [at for _, at in run.published]
        per_frame[pipelined] = (times[frames] - times[0]) / frames
    serial, pipelined = per_frame[False], per_frame[True]
    assert serial >= 0.95 * 2 * stage_s, per_frame  # the serial worker pays for both stages
    assert pipelined < 0.75 * 2 * stage_s, per_frame
    assert pipelined < 0.75 * serial, per_frame


def test_the_render_stage_starts_late_enough_that_its_frame_does_not_wait_for_detection(
    monkeypatch,
):
    # Detection is the slow stage: rendering the next frame as soon as detection starts
    # would age it by a whole detection (latency ~ 2 x detect); started just in time, a
    # frame's latency stays near render + detect, and detection never waits for it.
    render_s, detect_s = 0.02, 0.08
    stages = Stages(render_s=render_s, detect_s=detect_s)
    stages.install(monkeypatch)
    run = Run(True)
    try:
        run.feed_until(16)
    finally:
        run.worker.stop()
    latencies = [at - stamp / 1e9 for stamp, at in run.published[6:]]  # after the estimates
    times = [at for _, at in run.published[6:]]
    assert np.median(latencies) < render_s + detect_s + (detect_s - render_s) / 2, latencies
    assert np.median(np.diff(times)) < 1.2 * detect_s, np.diff(times)


def test_opengl_is_called_from_one_thread_only_across_a_camera_change_and_the_stop(
    monkeypatch,
):
    stages = Stages(render_s=0.005, detect_s=0.005)
    stages.install(monkeypatch)
    run = Run(True)
    try:
        run.feed_until(5)
        run.camera = OTHER_CAMERA  # camera_info changes: the renderer is rebuilt
        run.feed_until(10)
    finally:
        run.worker.stop()
    assert not any(thread.is_alive() for thread in run.worker._threads)
    assert stages.built == [CAMERA, OTHER_CAMERA] and stages.closed == [CAMERA, OTHER_CAMERA]
    assert len(set(stages.gl_threads)) == 1
    assert set(stages.detect_threads).isdisjoint(stages.gl_threads)  # detection ran beside
    # Each new renderer is warmed up (it renders) on the GL thread before its first frame.
    assert len(stages.warmed_up) == 2 and set(stages.warmed_up) == set(stages.gl_threads)


@pytest.mark.parametrize("pipelined", [True, False])
def test_stop_ends_every_thread_promptly_while_frames_flow(monkeypatch, pipelined):
    stages = Stages(render_s=0.01, detect_s=0.02)
    stages.install(monkeypatch)
    run = Run(pipelined)
    run.feed_until(3)
    feeding = threading.Event()

    def feed():
        while not feeding.is_set():
            run.put(time.monotonic_ns())
            time.sleep(0.002)

    feeder = threading.Thread(target=feed)
    feeder.start()
    try:
        start = time.monotonic()
        run.worker.stop(timeout_s=5.0)
        stopped_in = time.monotonic() - start
        count = len(run.published)
        time.sleep(0.2)
    finally:
        feeding.set()
        feeder.join()
    assert not any(thread.is_alive() for thread in run.worker._threads)
    assert stopped_in < 2.0
    assert len(run.published) == count  # nothing after stop() returned
    assert run.logger.fatal_lines == []  # a requested stop is no failure


@pytest.mark.parametrize("pipelined", [True, False])
def test_the_score_map_is_made_and_published_only_while_someone_reads_it(monkeypatch, pipelined):
    stages = Stages()
    stages.install(monkeypatch)
    readers = [0]
    run = Run(pipelined, score_wanted=lambda: readers[0] > 0)
    try:
        run.feed_until(3)
        readers[0] = 1
        count = len(run.published)
        run.feed_until(count + 3)
    finally:
        run.worker.stop()
    assert stages.score_maps == run.score_maps  # publish is told what detect made
    assert run.score_maps[:3] == [False] * 3 and run.score_maps[-2:] == [True] * 2


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_a_dead_detect_thread_makes_the_worker_not_alive_and_says_so(monkeypatch):
    stages = Stages()
    stages.install(monkeypatch)
    run = Run(True)

    def die(msg, image, frame, score_map):
        raise SystemExit("injected fault")

    run.worker._publish = die
    try:
        run.put(1)
        assert wait_until(lambda: not run.worker.is_alive())
        assert [t.name for t in run.worker._threads if t.is_alive()] == ["mrad_render"]
        lines = run.logger.fatal_lines
        assert any("processing thread stopped (mrad_detect)" in line for line in lines)
    finally:
        run.worker.stop()


def test_the_hand_over_holds_one_frame_and_wakes_waiters_on_close():
    handover = HandOver()
    assert handover.put("a", timeout=0.1)
    assert not handover.wait_empty(0.01) and not handover.put("b", timeout=0.01)
    before = time.monotonic()
    assert handover.take(0.1) == "a" and before <= handover.taken_at <= time.monotonic()
    assert handover.take(0.01) is None and handover.taken_at >= before
    woke = []
    waiter = threading.Thread(target=lambda: woke.append(handover.take(30)))
    waiter.start()
    handover.close()
    waiter.join(5)
    assert woke == [None] and not handover.put("c", timeout=0.01)
