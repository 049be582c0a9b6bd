"""Shutting the node down: a signal stops the processing threads before the ROS context goes,
a publish into a context shut down under it ends the run without a report, and a second
signal ends the node at once with status 130.

The node process holds a frame at publish time (``ALLO_HOLD_AT``), so the signal lands while
a frame is being published on any machine, however fast or slow.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
import types
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from sensor_msgs.msg import Image
from std_msgs.msg import Bool

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.pipeline import ProcessedFrame
from allo_mrad_ros.ros.buffers import LatestSlot
from allo_mrad_ros.ros.messages import fill_image
from allo_mrad_ros.ros.worker import HOLD_PUBLISH, HOLD_PUBLISH_STUCK, ProcessingWorker, Snapshot
from allo_mrad_ros.staging import HOLD_AT, HOLD_MARKER
from harness.feed import CameraFeed

pytestmark = pytest.mark.ros

CAMERA = CameraIntrinsics(8, 6, 8.0, 8.0, 4.0, 3.0)
INTRINSICS = CameraIntrinsics(320, 180, 222.2, 222.2, 160.0, 90.0)
POSE = look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0])
IMAGE = np.full((180, 320, 3), 40, np.uint8)
STOPPING = "stopping the processing threads"
# Longest wait for anything the node does (start-up, a frame, a shutdown) on a slow machine.
LIMIT_S = 120.0


class Lines:
    """A logger (or diagnostics) that keeps what it is told."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.stages = types.SimpleNamespace(record=lambda *a: None)

    def report(self, error, detail=""):
        self.lines.append(f"report: {error}")

    def count(self, *args):
        pass

    def __getattr__(self, level):
        return lambda text, *a, **k: self.lines.append(f"{level}: {text}")


class FastPipeline:
    provider = types.SimpleNamespace(
        camera=CAMERA,
        render=lambda view, time_s=None: np.zeros((6, 8, 3), np.uint8),
        close=lambda: None,
        reuse=None,
        reference_camera=CAMERA,
    )

    def detect(self, image, reference, score_map=True, view=None):
        result = types.SimpleNamespace(anomalous=False)
        return ProcessedFrame(reference, {"MRAD": result}, {"render": 0.0, "MRAD": 0.0})

    def close(self) -> None:
        pass


@pytest.mark.parametrize("pipelined", [True, False])
def test_a_publish_into_a_context_shut_down_under_it_ends_the_run_without_a_report(
    monkeypatch, pipelined
):
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node("shutdown_probe", context=context)
    publisher = node.create_publisher(Bool, "shutdown_probe", 1)
    entered, release = threading.Event(), threading.Event()
    failures: list[Exception] = []

    def publish(*args):
        entered.set()
        release.wait(LIMIT_S)
        try:
            publisher.publish(Bool(data=True))
        except Exception as error:
            failures.append(error)
            raise

    monkeypatch.setattr(
        ProcessingWorker, "_pipeline_for", lambda self, state, p, b: (FastPipeline(), b)
    )
    state = Snapshot(CAMERA, None, np.ones(3), 1.0, ())
    slot, said = LatestSlot(), Lines()
    worker = ProcessingWorker(
        slot,
        lambda _msg=None: state,
        lambda msg, s: "view",
        publish,
        said,
        said,
        pipelined,
        context_ok=context.ok,
    )
    try:
        slot.put((fill_image(Image(), None, np.zeros((6, 8, 3), np.uint8), "rgb8"), 0.0))
        assert entered.wait(LIMIT_S)
        context.handle.shutdown()  # what rclpy's signal handler does, whatever is under way
        release.set()
        worker.join(LIMIT_S)
        assert not worker.is_alive() and not any(t.is_alive() for t in worker._threads)
        assert failures and "context is invalid" in str(failures[0])  # the case meant
        assert said.lines == []  # no "frame failed", no "processing thread stopped"
    finally:
        release.set()
        worker.stop(1.0)
        node.destroy_node()


def _start(log: Path, marker: Path, hold: str) -> subprocess.Popen:
    """The node as a terminal starts it (SIGINT not ignored), held at publish time."""
    arguments = [sys.executable, "-m", "allo_mrad_ros.ros.node", "--ros-args"]
    # No age bound: on a loaded machine every frame may be older than the default 0.1 s
    # when taken, and the frame to hold at publish time would never come.
    for parameter in ("pose_source:=topic", "reference_scale:=0.25", "max_input_age_s:=0.0"):
        arguments += ["-p", parameter]
    env = {**os.environ, HOLD_AT: hold, HOLD_MARKER: str(marker)}
    return subprocess.Popen(
        arguments,
        stdout=log.open("w"),
        stderr=subprocess.STDOUT,
        env=env,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def _wait(process: subprocess.Popen, ready, what: str, log: Path, feed: CameraFeed | None = None):
    end = time.monotonic() + LIMIT_S
    stamp = 1_900_000_000 * 10**9
    while not ready():
        if process.poll() is not None:
            pytest.fail(f"the node ended ({process.returncode}) before {what}:\n{log.read_text()}")
        if time.monotonic() > end:
            process.kill()
            pytest.fail(f"no {what} within {LIMIT_S} s:\n{log.read_text()}")
        if feed is not None:
            stamp += 10**7
            feed.publish_frame(stamp, IMAGE, POSE)
            feed.spin(0.1)
        else:
            time.sleep(0.01)


@pytest.fixture(scope="module")
def feed():
    rclpy.init()
    peer = CameraFeed(INTRINSICS, keep_messages=False)
    yield peer
    peer.node.destroy_node()
    rclpy.shutdown()


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_while_a_frame_is_published_stops_the_node_cleanly(tmp_path, feed, signum):
    log, marker = tmp_path / "node.log", tmp_path / "held"
    process = _start(log, marker, HOLD_PUBLISH)
    try:
        _wait(process, marker.exists, "a frame held at publish time", log, feed)
        process.send_signal(signum)
        process.wait(LIMIT_S)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    text = log.read_text()
    assert process.returncode == 0, text
    assert not [line for line in text.splitlines() if "ERROR" in line or "FATAL" in line], text
    assert "Traceback" not in text and "context is invalid" not in text, text
    assert f"{signum.name} received: {STOPPING}" in text


def test_a_second_sigint_ends_the_node_at_once_quietly_with_status_130(tmp_path, feed):
    log, marker = tmp_path / "node.log", tmp_path / "held"
    process = _start(log, marker, HOLD_PUBLISH_STUCK)
    try:
        _wait(process, marker.exists, "a frame stuck at publish time", log, feed)
        process.send_signal(signal.SIGINT)
        _wait(process, lambda: STOPPING in log.read_text(), "orderly shutdown", log)
        process.send_signal(signal.SIGINT)
        # The stuck frame holds the orderly shutdown for a minute: only the second signal
        # can end the node before the limit.
        process.wait(LIMIT_S / 4)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    text = log.read_text()
    assert process.returncode == 130, text
    assert "Traceback" not in text and "KeyboardInterrupt" not in text, text


def test_the_lifecycle_node_waiting_unconfigured_stops_on_a_signal(tmp_path, feed):
    # Unconfigured it has no timer: only the signal itself can wake its executor.
    log = tmp_path / "node.log"
    # A namespace of its own: an earlier test's node may linger in the graph a while.
    namespace = f"/unconfigured_{os.getpid()}"
    argv = [sys.executable, "-m", "allo_mrad_ros.ros.lifecycle", "--ros-args"]
    argv += ["-r", f"__ns:={namespace}", "-p", "pose_source:=topic"]
    process = subprocess.Popen(argv, stdout=log.open("w"), stderr=subprocess.STDOUT)

    def up() -> bool:
        return ("mrad_detector", namespace) in feed.node.get_node_names_and_namespaces()

    try:
        _wait(process, up, "the node", log)
        process.send_signal(signal.SIGTERM)
        process.wait(LIMIT_S)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    text = log.read_text()
    assert process.returncode == 0 and f"SIGTERM received: {STOPPING}" in text, text


def test_a_sigint_ignored_at_start_stays_ignored():
    # A command started in the background by a shell: Ctrl-C in the terminal is not for it.
    code = (
        "import signal; signal.signal(signal.SIGINT, signal.SIG_IGN); "
        "from allo_mrad_ros.ros.shutdown import ShutdownSignals; ShutdownSignals(); "
        "print(signal.getsignal(signal.SIGINT) is signal.SIG_IGN, "
        "signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.stdout.split() == ["True", "True"], done.stderr
