"""The node's counters and its ``/diagnostics`` status (rate, per-stage latency, problems).

The level describes the recent past, not the whole run, as diagnostic_updater's frequency and
timestamp tasks do: problems count towards WARN only while they are younger than a sliding
window, the rate is measured over the window up to now, no image for ``input_timeout_s`` is
STALE and a dead processing thread is ERROR. Totals since start stay in the values.
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
        Publishes ``/diagnostics`` on a timer of ``period_s``.
    period_s : float
        Publishing period.
    received : callable
        Returns the number of images received so far.
    pose_source : str
        Reported as a value.
    input_timeout_s : float
        No image for this long: level STALE.
    hardware_id : str
        ``hardware_id`` of the status; empty: the frame id of the latest image.
    """

    def __init__(
        self,
        node: Node,
        period_s: float,
        received: Callable[[], int],
        pose_source: str,
        input_timeout_s: float = 2.0,
        hardware_id: str = "",
    ) -> None:
        self._node = node
        self._received = received
        self.pose_source = pose_source
        self.input_timeout_s = input_timeout_s
        self.window_s = max(5.0, 5.0 * period_s)
        self._hardware_id = hardware_id
        self._frame_id = ""
        self._last_input: float | None = None
        self.worker_alive: Callable[[], bool] = lambda: True
        self._counters: Counter[str] = Counter()
        self._recent: deque[tuple[float, str]] = deque(maxlen=10_000)
        self._logged_kinds: set[str] = set()
        self._lock = threading.Lock()
        self.stages = StageStatistics(window=1000)
        self._publisher = node.create_publisher(DiagnosticArray, interface.DIAGNOSTICS_TOPIC, 10)
        node.create_timer(period_s, self.publish)

    def input_seen(self, frame_id: str) -> None:
        """Note that an image arrived now (its frame names the hardware)."""
        with self._lock:
            self._last_input = time.monotonic()
            self._frame_id = frame_id

    def count(self, name: str) -> None:
        """Add one to counter ``name`` (and to the recent window)."""
        with self._lock:
            self._counters[name] += 1
            self._recent.append((time.monotonic(), name))

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

    def status(self) -> DiagnosticStatus:
        """The pipeline's current status."""
        now = time.monotonic()
        with self._lock:
            counters = dict(self._counters)
            recent = self._recent_counts(now)
            last_input, frame_id = self._last_input, self._frame_id
        counters["frames_received"] = self._received()
        status = DiagnosticStatus(
            # Fully qualified (less the root slash): two cameras' nodes stay apart.
            name=f"{self._node.get_fully_qualified_name().lstrip('/')}: pipeline",
            hardware_id=self._hardware_id or frame_id or interface.HARDWARE_ID,
        )
        values = {
            "rate_hz": f"{self.stages.rate_hz(self.window_s):.2f}",
            "pose_source": self.pose_source,
            "window_s": f"{self.window_s:g}",
        }
        for stage, (p50, p95) in self.stages.percentiles().items():
            values[f"latency_{stage}_ms_p50"] = f"{p50:.1f}"
            values[f"latency_{stage}_ms_p95"] = f"{p95:.1f}"
        values.update({name: str(count) for name, count in sorted(counters.items())})
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        problems = sorted(
            k for k in recent if k.startswith("errors_") or k == "pose_lookup_failures"
        )
        silent_s = None if last_input is None else now - last_input
        if not self.worker_alive():
            status.level = DiagnosticStatus.ERROR
            status.message = "processing thread stopped: no frames are processed"
        elif silent_s is None or silent_s > self.input_timeout_s:
            status.level = DiagnosticStatus.STALE
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
        else:
            status.level = DiagnosticStatus.OK
            status.message = "running"
        return status

    def publish(self) -> None:
        """Publish :meth:`status` on ``/diagnostics``."""
        array = DiagnosticArray(status=[self.status()])
        array.header.stamp = self._node.get_clock().now().to_msg()
        self._publisher.publish(array)
