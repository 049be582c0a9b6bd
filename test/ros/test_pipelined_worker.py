"""The two-stage processing worker with stand-in render and detect stages (no DDS, no GL).

The stand-ins record which thread called them and when each stage of each frame starts and
ends (in order, not in seconds); a test can hold a frame's detection until it has seen what
it waits for, so the overlap of the stages is shown by the order of events, whatever the
machine's speed or load. The render thread's timing rule is checked on an injected clock.
"""

import itertools
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
from allo_mrad_ros.ros.worker import ProcessingWorker, Snapshot, render_delay_s

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


class ThreadClocks:
    """An injected ``perf_counter``: each thread's own virtual time, moved only by
    :meth:`advance` (the stand-in stages), so a stage measures exactly what it declares."""

    def __init__(self):
        self._local = threading.local()

    def perf_counter(self):
        return getattr(self._local, "now", 0.0)

    def advance(self, seconds):
        self._local.now = self.perf_counter() + seconds

    def install(self, monkeypatch):
        names = {name: getattr(time, name) for name in dir(time) if not name.startswith("_")}
        clock = types.SimpleNamespace(**{**names, "perf_counter": self.perf_counter})
        monkeypatch.setattr(worker_module, "time", clock)


class Stages:
    """Stand-in render and detect: sleep (or advance an injected clock), record the calling
    thread and each stage's start and end per frame, optionally block."""

    def __init__(self, render_s=0.0, detect_s=0.0, clocks=None):
        self.render_s, self.detect_s = render_s, detect_s
        self.clocks = clocks
        self.gl_threads, self.detect_threads = [], []
        self.built, self.closed, self.score_maps, self.warmed_up = [], [], [], []
        self.gate = threading.Event()
        self.gate.set()
        self.detecting = threading.Event()
        # (stage, "start" or "end", frame stamp in s, thread), in the order they happened.
        self.events = []
        self.changed = threading.Condition()
        # Frame stamp (s) -> Event its detection waits for once started.
        self.holds = {}
        self._frames = {}  # id of a rendered reference -> its frame's stamp (s)

    def record(self, stage, edge, frame):
        with self.changed:
            self.events.append((stage, edge, frame, threading.get_ident()))
            self.changed.notify_all()

    def wait_for_event(self, event, timeout_s=30.0):
        """Wait until ``(stage, edge, frame)`` has happened; True if it has."""
        with self.changed:
            return self.changed.wait_for(
                lambda: event in [e[:3] for e in self.events], timeout=timeout_s
            )

    def index(self, stage, edge, frame):
        return [e[:3] for e in self.events].index((stage, edge, frame))

    def spend(self, duration):
        if self.clocks is not None:
            self.clocks.advance(seconds(duration))
        else:
            time.sleep(seconds(duration))

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
                stages.record("render", "start", time_s)
                stages.spend(stages.render_s)
                reference = np.zeros((self.camera.height, self.camera.width, 3), np.uint8)
                stages._frames[id(reference)] = (time_s, reference)  # kept: ids stay unique
                stages.record("render", "end", time_s)
                return reference

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

            def detect(self, image, reference, score_map=True, view=None):
                frame = stages._frames[id(reference)][0]
                stages.record("detect", "start", frame)
                stages.detect_threads.append(threading.get_ident())
                stages.score_maps.append(score_map)
                stages.detecting.set()
                stages.gate.wait(30)
                hold = stages.holds.get(frame)
                if hold is not None:
                    hold.wait(30)
                stages.spend(stages.detect_s)
                stages.record("detect", "end", frame)
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


def test_the_next_frame_is_rendered_while_this_one_is_detected(monkeypatch):
    # Each frame's detection is held until the next frame's render has ended: the two stages
    # run at once, so a frame costs the slower stage, not the sum. (Without the overlap the
    # wait below would time out: the held detection never ends.)
    stages = Stages()
    stages.install(monkeypatch)
    frames = [float(n) for n in range(1, 6)]
    for frame in frames:
        stages.holds[frame] = threading.Event()
    run = Run(True)
    try:
        run.put(int(frames[0] * 1e9))
        for frame, following in itertools.pairwise(frames):
            assert stages.wait_for_event(("detect", "start", frame)), stages.events
            run.put(int(following * 1e9))
            assert stages.wait_for_event(("render", "end", following)), stages.events
            stages.holds[frame].set()
        stages.holds[frames[-1]].set()
        assert wait_until(lambda: len(run.published) == len(frames))
    finally:
        run.worker.stop()
    for frame, following in itertools.pairwise(frames):
        assert stages.index("render", "start", following) < stages.index("detect", "end", frame)
        assert stages.index("render", "end", following) < stages.index("detect", "end", frame)
    render_threads = {e[3] for e in stages.events if e[0] == "render"}
    detect_threads = {e[3] for e in stages.events if e[0] == "detect"}
    assert len(render_threads) == len(detect_threads) == 1 and render_threads != detect_threads
    assert [stamp / 1e9 for stamp, _ in run.published] == frames


def test_the_serial_worker_renders_a_frame_only_after_the_last_one_is_detected(monkeypatch):
    stages = Stages()
    stages.install(monkeypatch)
    run = Run(False)
    try:
        for frame in range(1, 6):
            run.put(frame * 10**9)
            assert stages.wait_for_event(("detect", "end", float(frame))), stages.events
    finally:
        run.worker.stop()
    stages_in_order = [(stage, edge) for stage, edge, _, _ in stages.events]
    assert (
        stages_in_order
        == [
            ("render", "start"),
            ("render", "end"),
            ("detect", "start"),
            ("detect", "end"),
        ]
        * 5
    )
    assert [frame for _, _, frame, _ in stages.events] == [
        float(f) for f in range(1, 6) for _ in range(4)
    ]
    assert len({thread for *_, thread in stages.events}) == 1


@pytest.mark.parametrize("render_ms, detect_ms", [(20.0, 80.0), (5.0, 200.0), (1.0, 30.0)])
def test_the_render_is_timed_to_end_just_before_the_detection_it_feeds(render_ms, detect_ms):
    # Detection is the slow stage: rendering the next frame as soon as detection starts
    # would age it by a whole detection; started just in time it is fresh, and detection
    # never waits for it.
    taken_at = 1000.0
    delay = render_delay_s(taken_at, detect_ms, render_ms, taken_at)
    render_ends = taken_at + delay + render_ms / 1e3
    detect_ends = taken_at + detect_ms / 1e3
    assert delay > 0
    assert render_ends <= detect_ends  # the detect thread does not wait for the frame
    # ... and the frame is not older than a share of a render (plus a few ms) when taken.
    assert detect_ends - render_ends <= 0.5 * render_ms / 1e3 + 0.005
    # Later calls wait for what is left of the same moment.
    assert render_delay_s(taken_at, detect_ms, render_ms, taken_at + delay / 2) == pytest.approx(
        delay / 2
    )
    assert render_delay_s(taken_at, detect_ms, render_ms, taken_at + delay + 1e-3) == 0.0


@pytest.mark.parametrize(
    "taken_at, detect_ms, render_ms",
    [
        (None, 80.0, 20.0),  # nothing in detection yet
        (1000.0, None, 20.0),  # no estimates yet
        (1000.0, 80.0, None),
        (1000.0, 20.0, 20.0),  # rendering is as slow as detection: start at once
        (1000.0, 20.0, 80.0),
    ],
)
def test_the_render_starts_at_once_without_estimates_or_when_rendering_is_the_slow_stage(
    taken_at, detect_ms, render_ms
):
    assert render_delay_s(taken_at, detect_ms, render_ms, 1000.0) == 0.0


def test_the_worker_times_its_renders_by_its_own_stage_estimates(monkeypatch):
    # On an injected clock each stand-in stage takes exactly what it declares, so the
    # worker's running estimates must come out as those values, and the render thread
    # must ask when to render with them and with the moment detection took its frame.
    clocks = ThreadClocks()
    clocks.install(monkeypatch)
    stages = Stages(render_s=0.020, detect_s=0.080, clocks=clocks)
    stages.install(monkeypatch)
    asked = []

    def spy(taken_at, detect_ms, render_ms, now):
        asked.append((taken_at, detect_ms, render_ms, now))
        return 0.0  # render at once: the rule itself is tested above

    monkeypatch.setattr(worker_module, "render_delay_s", spy)
    run = Run(True)
    try:
        for frame in range(1, 5):
            run.put(frame * 10**9)
            assert stages.wait_for_event(("detect", "end", float(frame))), stages.events
            assert wait_until(lambda frame=frame: len(run.published) == frame)
    finally:
        run.worker.stop()
    informed = [a for a in asked if None not in a[:3]]
    assert informed, asked
    for taken_at, detect_ms, render_ms, now in informed:
        assert detect_ms == pytest.approx(80.0) and render_ms == pytest.approx(20.0)
        assert taken_at <= now


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


STOP_TIMEOUT_S = 30.0


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
        run.worker.stop(timeout_s=STOP_TIMEOUT_S)
        stopped_in = time.monotonic() - start
        count = len(run.published)
        time.sleep(0.2)
    finally:
        feeding.set()
        feeder.join()
    assert not any(thread.is_alive() for thread in run.worker._threads)
    # The threads ended of themselves, stop() did not give up on them at its timeout (on a
    # loaded machine a frame in progress may take seconds: no tighter bound holds there).
    assert stopped_in < STOP_TIMEOUT_S
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
    # Publish is told what detect made (a frame detected while stop() ran is not published).
    assert stages.score_maps[: len(run.score_maps)] == run.score_maps
    assert len(stages.score_maps) - len(run.score_maps) in (0, 1)
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
