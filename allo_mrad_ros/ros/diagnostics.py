"""The node's counters and its ``/diagnostics`` statuses.

Three statuses per message: ``<node>: pipeline`` (rate, per-stage latency, the age of the frames
when taken and when published, problems, counters),
``<node>: input rate`` and ``<node>: input stamp``, the last two with the keys and levels of
diagnostic_updater's FrequencyStatus and TimeStampStatus. Levels describe the recent past: a
problem counts towards WARN only while younger than a sliding window; no image for
``input_timeout_s`` while an output is subscribed is ERROR; with no output subscribed the node
is idle on purpose, which is OK. STALE is the aggregator's call, never the node's.
"""

from __future__ import annotations

import re
import threading
import time
from collections import Counter, deque
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from allo_mrad_ros import interface
from allo_mrad_ros.ros.buffers import StageStatistics
from allo_mrad_ros.ros.messages import MessageError
from allo_mrad_ros.ros.parameters import NodeConfig

# Distinct error kinds logged once each; beyond this many a cause is only counted.
_MAX_LOGGED_KINDS = 200


def _kind(error: MessageError) -> str:
    """The cause plus the message with its numbers blanked: one log line per kind of problem,
    not per stamp or size."""
    return f"{error.cause}: {re.sub(r'[-+]?[0-9][0-9.e+-]*', '#', str(error))}"


class Diagnostics:
    """Counts frames and input errors, logs each kind of error once, publishes the status.

    Parameters
    ----------
    node : rclpy.node.Node
        Publishes ``/diagnostics`` on a timer of ``config.diagnostics_period_s``.
    config : NodeConfig
        Read at construction (every field used is read-only): ``diagnostics_period_s``,
        ``input_timeout_s`` (no image for this long while an output is subscribed: level
        ERROR), ``hardware_id`` (empty: the frame id of the latest image), ``expected_rate_hz``
        and ``rate_tolerance`` (the input rate status' target, 0: none, and its accepted
        relative deviation), ``max_stamp_delay_s`` (the input stamp status' largest accepted
        stamp age on arrival).
    received : callable
        Returns the number of images received so far.
    pose_source : callable
        Returns the pose source in use, reported as a value.
    idle : callable
        Returns why the node processes nothing on purpose ("" when it should be processing).
    inputs_subscribed : callable
        Returns whether the node is subscribed to the image now.
    input_publishers : callable
        Returns, by input (``image``, ``camera_info``), the publishers its subscription has
        matched, reported as ``<input>_publishers``: a camera's first image is sure to arrive
        once they are up.
    worker_alive : callable
        Returns whether the processing thread runs.
    """

    def __init__(
        self,
        node: Node,
        config: NodeConfig,
        *,
        received: Callable[[], int],
        pose_source: Callable[[], str],
        idle: Callable[[], str] = lambda: "",
        inputs_subscribed: Callable[[], bool] = lambda: True,
        input_publishers: Callable[[], dict[str, int]] = dict,
        worker_alive: Callable[[], bool] = lambda: True,
    ) -> None:
        self._node = node
        self._received = received
        self._pose_source = pose_source
        self._idle = idle
        self._inputs_subscribed = inputs_subscribed
        self._input_publishers = input_publishers
        self._worker_alive = worker_alive
        self.input_timeout_s = config.input_timeout_s
        self.window_s = max(5.0, 5.0 * config.diagnostics_period_s)
        self._hardware_id = config.hardware_id
        self._frame_id = ""
        self._last_input: float | None = None
        self.expected_rate_hz = config.expected_rate_hz
        self.rate_tolerance = config.rate_tolerance
        self.max_stamp_delay_s = config.max_stamp_delay_s
        self._arrivals: deque[float] = deque(maxlen=100_000)
        self._arrivals_total = 0
        # Stamp delays (s) of images since the last publication: TimeStampStatus' window.
        self._delays: list[float] = []
        self._zero_stamps = 0
        self._late_updates = 0
        self._early_updates = 0
        self._zero_updates = 0
        self._counters: Counter[str] = Counter()
        # Values that are a state, not a count (the tracker's objects): the latest of each.
        self._values: dict[str, str] = {}
        self._recent: deque[tuple[float, str]] = deque(maxlen=10_000)
        self._logged_kinds: set[str] = set()
        self._lock = threading.Lock()
        self.stages = StageStatistics(window=1000)
        self._publisher = node.create_publisher(DiagnosticArray, interface.DIAGNOSTICS_TOPIC, 10)
        node.create_timer(config.diagnostics_period_s, self.publish)

    def input_seen(self, frame_id: str, stamp_ns: int = 0, now_ns: int = 0) -> None:
        """Note that an image arrived now (its frame names the hardware); ``now_ns - stamp_ns``
        is its stamp delay on the node's clock (stamp 0: counted as a zero stamp)."""
        with self._lock:
            self._last_input = time.monotonic()
            self._arrivals.append(self._last_input)
            self._arrivals_total += 1
            self._frame_id = frame_id
            if stamp_ns == 0:
                self._zero_stamps += 1
            else:
                self._delays.append((now_ns - stamp_ns) / 1e9)

    def count(self, name: str) -> None:
        """Add one to counter ``name`` (and to the recent window)."""
        with self._lock:
            self._counters[name] += 1
            self._recent.append((time.monotonic(), name))

    def set_values(self, values: dict[str, str]) -> None:
        """Report ``values`` (name to text) from now on, replacing their earlier values."""
        with self._lock:
            self._values.update(values)

    def report(self, error: MessageError, detail: str = "") -> None:
        """Count an input error; log each kind once so a bad stream cannot flood the log.

        ``detail`` (a traceback, say) is appended to that one log line.
        """
        self.count(f"errors_{error.cause}")
        kind = _kind(error)
        with self._lock:
            first = kind not in self._logged_kinds and len(self._logged_kinds) < _MAX_LOGGED_KINDS
            if first:  # past the cap nothing more is logged, so nothing more is remembered
                self._logged_kinds.add(kind)
        if first:
            self._node.get_logger().error(
                f"{error} (further '{error.cause}' errors of this kind are counted in "
                f"/diagnostics){detail}"
            )

    def _recent_counts(self, now: float) -> Counter[str]:
        while self._recent and self._recent[0][0] < now - self.window_s:
            self._recent.popleft()
        return Counter(name for _, name in self._recent)

    def _name(self, what: str) -> str:
        # Fully qualified (less the root slash): two cameras' nodes stay apart.
        return f"{self._node.get_fully_qualified_name().lstrip('/')}: {what}"

    def status(self) -> DiagnosticStatus:
        """The pipeline's current status."""
        now = time.monotonic()
        with self._lock:
            counters = dict(self._counters)
            states = dict(self._values)
            recent = self._recent_counts(now)
            last_input, frame_id = self._last_input, self._frame_id
        counters["frames_received"] = self._received()
        idle = self._idle()
        status = DiagnosticStatus(
            name=self._name("pipeline"),
            hardware_id=self._hardware_id or frame_id or interface.HARDWARE_ID,
        )
        values = {
            "rate_hz": f"{self.stages.rate_hz(self.window_s):.2f}",
            "pose_source": self._pose_source(),
            "window_s": f"{self.window_s:g}",
            "inputs_subscribed": str(self._inputs_subscribed()).lower(),
        }
        for name, count in self._input_publishers().items():
            values[f"{name}_publishers"] = str(count)
        for stage, (p50, p95) in self.stages.percentiles().items():
            # A stage's time is latency_<stage>; a frame's age (since its image was
            # published) when taken and when published is input_age_<taken|published>.
            key = f"input_{stage}" if stage.startswith("age_") else f"latency_{stage}"
            values[f"{key}_ms_p50"] = f"{p50:.1f}"
            values[f"{key}_ms_p95"] = f"{p95:.1f}"
        values.update({name: str(count) for name, count in sorted(counters.items())})
        values.update(sorted(states.items()))
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        problems = sorted(
            k for k in recent if k.startswith("errors_") or k == "pose_lookup_failures"
        )
        silent_s = None if last_input is None else now - last_input
        if not self._worker_alive():
            status.level = DiagnosticStatus.ERROR
            status.message = "processing thread stopped: no frames are processed"
        elif idle:
            status.level = DiagnosticStatus.OK
            status.message = f"idle: {idle}"
        elif silent_s is None or silent_s > self.input_timeout_s:
            status.level = DiagnosticStatus.ERROR
            status.message = (
                f"no image on {interface.IMAGE_TOPIC} yet"
                if silent_s is None
                else f"no image on {interface.IMAGE_TOPIC} for {silent_s:.1f} s"
            )
        elif problems:
            status.level = DiagnosticStatus.WARN
            status.message = f"input problems in the last {self.window_s:g} s: " + ", ".join(
                problems
            )
        elif recent.get("frames_processed", 0) == 0:
            status.level = DiagnosticStatus.WARN
            status.message = f"images arrive but none processed in the last {self.window_s:g} s"
            too_old = recent.get("frames_dropped_too_old", 0)
            if too_old:
                status.message += f" ({too_old} dropped as older than max_input_age_s)"
        else:
            status.level = DiagnosticStatus.OK
            status.message = "running"
        return status

    def frequency_status(self, idle: str = "") -> DiagnosticStatus:
        """Image arrivals over the window, as diagnostic_updater's FrequencyStatus reports."""
        now = time.monotonic()
        with self._lock:
            while self._arrivals and self._arrivals[0] < now - self.window_s:
                self._arrivals.popleft()
            events, total = len(self._arrivals), self._arrivals_total
        frequency = events / self.window_s
        status = DiagnosticStatus(
            name=self._name("input rate"),
            hardware_id=self._hardware_id or self._frame_id or interface.HARDWARE_ID,
        )
        values = {
            "Events in window": str(events),
            "Events since startup": str(total),
            "Duration of window (s)": f"{self.window_s:g}",
            "Actual frequency (Hz)": f"{frequency:.3f}",
        }
        expected = self.expected_rate_hz
        low, high = expected * (1 - self.rate_tolerance), expected * (1 + self.rate_tolerance)
        if expected > 0:
            values["Target frequency (Hz)"] = f"{expected:g}"
            values["Minimum acceptable frequency (Hz)"] = f"{low:g}"
            values["Maximum acceptable frequency (Hz)"] = f"{high:g}"
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        status.level, status.message = DiagnosticStatus.OK, "Desired frequency met"
        if idle:
            status.message = f"idle: {idle}"
        elif events == 0:
            status.level, status.message = DiagnosticStatus.ERROR, "No events recorded."
        elif expected > 0 and frequency < low:
            status.level, status.message = DiagnosticStatus.WARN, "Frequency too low."
        elif expected > 0 and frequency > high:
            status.level, status.message = DiagnosticStatus.WARN, "Frequency too high."
        elif expected == 0:
            status.message = "no expected_rate_hz set"
        return status

    def timestamp_status(self, idle: str = "") -> DiagnosticStatus:
        """Image stamp delays since the last publication, as diagnostic_updater's
        TimeStampStatus reports (acceptable delays -1 s .. ``max_stamp_delay_s``)."""
        with self._lock:
            delays, self._delays = self._delays, []
            zero, self._zero_stamps = self._zero_stamps, 0
            if delays and max(delays) > self.max_stamp_delay_s:
                self._late_updates += 1
            if delays and min(delays) < -1.0:
                self._early_updates += 1
            if zero:
                self._zero_updates += 1
            late, early, zeros = self._late_updates, self._early_updates, self._zero_updates
        status = DiagnosticStatus(
            name=self._name("input stamp"),
            hardware_id=self._hardware_id or self._frame_id or interface.HARDWARE_ID,
        )
        values = {
            "Earliest timestamp delay:": f"{min(delays):.6f}" if delays else "No data",
            "Latest timestamp delay:": f"{max(delays):.6f}" if delays else "No data",
            "Earliest acceptable timestamp delay:": "-1.000000",
            "Latest acceptable timestamp delay:": f"{self.max_stamp_delay_s:.6f}",
            "Late diagnostic update count:": str(late),
            "Early diagnostic update count:": str(early),
            "Zero seen diagnostic update count:": str(zeros),
        }
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        status.level, status.message = DiagnosticStatus.OK, "Timestamps are reasonable."
        if idle and not delays and not zero:
            status.message = f"idle: {idle}"
        elif not delays and not zero:
            status.level, status.message = DiagnosticStatus.WARN, "No data since last update."
        elif zero:
            status.level, status.message = DiagnosticStatus.ERROR, "Zero timestamp seen."
        elif max(delays) > self.max_stamp_delay_s:
            status.level = DiagnosticStatus.ERROR
            status.message = "Timestamps too far in past seen."
        elif min(delays) < -1.0:
            status.level = DiagnosticStatus.ERROR
            status.message = "Timestamps too far in future seen."
        return status

    def statuses(self) -> list[DiagnosticStatus]:
        """The pipeline status first, then the input rate and input stamp statuses."""
        idle = self._idle()
        return [self.status(), self.frequency_status(idle), self.timestamp_status(idle)]

    def publish(self) -> None:
        """Publish :meth:`statuses` on ``/diagnostics``."""
        if not self._node.context.ok():
            return  # shutting down
        array = DiagnosticArray(status=self.statuses())
        array.header.stamp = self._node.get_clock().now().to_msg()
        self._publisher.publish(array)
