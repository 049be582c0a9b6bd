"""The node's counters and its ``/diagnostics`` status (rate, per-stage latency, problems)."""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from allo_mrad_ros import interface
from allo_mrad_ros.ros.buffers import StageStatistics
from allo_mrad_ros.ros.messages import MessageError


class Diagnostics:
    """Counts frames and input errors, logs each error cause once, publishes the status.

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
    """

    def __init__(
        self, node: Node, period_s: float, received: Callable[[], int], pose_source: str
    ) -> None:
        self._node = node
        self._received = received
        self.pose_source = pose_source
        self._counters: Counter[str] = Counter()
        self._logged_causes: set[str] = set()
        self._lock = threading.Lock()
        self.stages = StageStatistics()
        self._publisher = node.create_publisher(DiagnosticArray, interface.DIAGNOSTICS_TOPIC, 10)
        node.create_timer(period_s, self.publish)

    def count(self, name: str) -> None:
        """Add one to counter ``name``."""
        with self._lock:
            self._counters[name] += 1

    def report(self, error: MessageError) -> None:
        """Count an input error; log it once per cause so a bad stream cannot flood the log."""
        self.count(f"errors_{error.cause}")
        with self._lock:
            first = error.cause not in self._logged_causes
            self._logged_causes.add(error.cause)
        if first:
            self._node.get_logger().error(
                f"{error} (further '{error.cause}' errors are counted in /diagnostics)"
            )

    def status(self) -> DiagnosticStatus:
        """The pipeline's current status."""
        with self._lock:
            counters = dict(self._counters)
        counters["frames_received"] = self._received()
        status = DiagnosticStatus(
            # Fully qualified (less the root slash): two cameras' nodes stay apart.
            name=f"{self._node.get_fully_qualified_name().lstrip('/')}: pipeline",
            hardware_id=interface.HARDWARE_ID,
        )
        values = {"rate_hz": f"{self.stages.rate_hz():.2f}", "pose_source": self.pose_source}
        for stage, (p50, p95) in self.stages.percentiles().items():
            values[f"latency_{stage}_ms_p50"] = f"{p50:.1f}"
            values[f"latency_{stage}_ms_p95"] = f"{p95:.1f}"
        values.update({name: str(count) for name, count in sorted(counters.items())})
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        problems = [k for k in counters if k.startswith("errors_") or k == "pose_lookup_failures"]
        if problems:
            status.level = DiagnosticStatus.WARN
            status.message = "input problems: " + ", ".join(sorted(problems))
        elif counters.get("frames_processed", 0) == 0:
            status.level = DiagnosticStatus.WARN
            status.message = "no frames processed yet"
        else:
            status.level = DiagnosticStatus.OK
            status.message = "running"
        return status

    def publish(self) -> None:
        """Publish :meth:`status` on ``/diagnostics``."""
        array = DiagnosticArray(status=[self.status()])
        array.header.stamp = self._node.get_clock().now().to_msg()
        self._publisher.publish(array)
