"""Record the running node's outputs and pair them with their input frames by stamp.

Used by ``make demo`` (live evaluation of a played bag): every time the score, the mask and
the result of a stamp have arrived, ``on_frame`` gets the two maps as arrays and the frame's
image score from the result, and the messages are dropped, so memory stays flat over long
bags. The arrival of the input image on the same topic the
node reads gives the end-to-end latency, input published (the middleware's source timestamp,
where rclpy passes it; else its arrival here) to output received. The node's
own ``/diagnostics`` pipeline status is kept too (:attr:`OutputRecorder.node_status`): its
figures of the frames' age when taken and when published do not depend on how promptly this
process, the recorder, gets the CPU.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image
from std_msgs.msg import Bool

from allo_mrad_ros import interface
from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.ros.messages import stamp_to_ns
from allo_mrad_ros.ros.rclpy_compat import message_info_callback


@dataclass(frozen=True)
class RecordedFrame:
    """The node's outputs for one input frame."""

    stamp_ns: int
    score: np.ndarray
    mask: np.ndarray
    image_score: float
    latency_ms: float | None


class RecorderError(InvalidInput):
    """A ``~/result`` message without a numeric ``image_score`` value."""


def image_score_of(result: DiagnosticArray) -> float:
    """The frame's image score, as the node's ``~/result`` reports it (the score I.AUROC ranks).

    Raises
    ------
    RecorderError
        If no status carries an ``image_score`` value that parses as a number.
    """
    for status in result.status:
        for value in status.values:
            if value.key == "image_score":
                try:
                    return float(value.value)
                except ValueError:
                    break
    raise RecorderError("the ~/result message has no numeric image_score value")


OUTPUTS = ("score", "mask", "result")


class OutputRecorder:
    """Subscribe to the node's ``score``, ``mask`` and ``result`` (and the input image for
    latency).

    Parameters
    ----------
    node : rclpy.node.Node
        The node to create subscriptions on.
    on_frame : callable
        Called with a :class:`RecordedFrame` once the three outputs of a stamp have arrived.
    node_name : str
        Fully qualified name of the detector node (its private topics are recorded).
    image_topic : str
        The input image topic, for end-to-end latency (empty to skip).
    capacity : int
        Stamps kept waiting for their other output, and input arrival times kept; beyond
        this the oldest are forgotten (counted in ``unmatched``), so outputs the node never
        completes (a dropped message, a skipped frame) cannot grow memory.

    Attributes
    ----------
    node_status : dict
        The values of the node's latest ``<node>: pipeline`` status on ``/diagnostics``
        (empty before the first).
    """

    def __init__(
        self,
        node: Node,
        on_frame: Callable[[RecordedFrame], None],
        node_name: str = "/" + interface.NODE_NAME,
        image_topic: str = interface.IMAGE_TOPIC,
        capacity: int = 256,
    ) -> None:
        self._on_frame = on_frame
        self._capacity = capacity
        self.unmatched = 0
        self._pending: dict[int, dict[str, Image | DiagnosticArray]] = {}
        self._input_arrival: dict[int, float] = {}
        self._lock = threading.Lock()
        self.anomaly_flags = 0
        self.frames = 0
        self.node_status: dict[str, str] = {}
        self._status_name = f"{node_name.lstrip('/')}: pipeline"
        node.create_subscription(Image, f"{node_name}/score", self._store("score"), 10)
        node.create_subscription(Image, f"{node_name}/mask", self._store("mask"), 10)
        node.create_subscription(DiagnosticArray, f"{node_name}/result", self._store("result"), 10)
        node.create_subscription(Bool, f"{node_name}/anomaly", self._on_anomaly, 10)
        node.create_subscription(
            DiagnosticArray, interface.DIAGNOSTICS_TOPIC, self._on_diagnostics, 10
        )
        if image_topic:
            node.create_subscription(
                Image,
                image_topic,
                # With the message info, where rclpy passes it: when the image was sent.
                message_info_callback(self._on_input),
                qos_profile_sensor_data,
            )

    def _on_input(self, msg: Image, info: Mapping[str, int] | None = None) -> None:
        # When the image was published (system clock, s), else when it arrived here.
        source_ns = 0 if info is None else int(info.get("source_timestamp") or 0)
        sent = source_ns / 1e9 if source_ns > 0 else time.time()
        with self._lock:
            self._input_arrival[stamp_to_ns(msg.header.stamp)] = sent
            _forget_oldest(self._input_arrival, self._capacity)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == self._status_name:
                self.node_status = {value.key: value.value for value in status.values}

    def _on_anomaly(self, msg: Bool) -> None:
        self.anomaly_flags += int(msg.data)

    def _store(self, kind: str) -> Callable[[Image | DiagnosticArray], None]:
        def store(msg: Image | DiagnosticArray) -> None:
            stamp = stamp_to_ns(msg.header.stamp)
            with self._lock:
                entry = self._pending.setdefault(stamp, {})
                entry[kind] = msg
                if len(entry) < len(OUTPUTS):
                    self.unmatched += _forget_oldest(self._pending, self._capacity)
                    return
                del self._pending[stamp]
                sent = self._input_arrival.pop(stamp, None)
            latency = None if sent is None else 1e3 * (time.time() - sent)
            score, mask = entry["score"], entry["mask"]
            self.frames += 1
            self._on_frame(
                RecordedFrame(
                    stamp,
                    np.frombuffer(score.data, np.float32).reshape(score.height, score.width),
                    np.frombuffer(mask.data, np.uint8).reshape(mask.height, mask.width),
                    image_score_of(entry["result"]),
                    latency,
                )
            )

        return store


def _forget_oldest(entries: dict, capacity: int) -> int:
    """Drop the oldest-inserted entries beyond ``capacity``; return how many."""
    excess = len(entries) - capacity
    for stamp in list(entries)[: max(0, excess)]:
        del entries[stamp]
    return max(0, excess)
