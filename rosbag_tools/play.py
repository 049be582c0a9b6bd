"""``allo-bag play``: publish a bag over DDS with rclpy, for machines without ``ros2 bag play``.

Messages go out at the bag's recorded pace (scaled by ``rate``), with their recorded header
stamps, in the bag's order. The CDR bytes from the bag are published as they are
(``Publisher.publish`` takes serialized bytes), so what subscribers receive is bit for bit
what was recorded; the first message of every topic is also decoded with rclpy's
``deserialize_message`` to catch a bag whose definition does not match the installed one.

A topic whose message type is not importable here (e.g. ``tf2_msgs``, which has no PyPI
wheel) is skipped with one warning. With ``clock=True`` the bag time is also published on
``/clock`` (``rosgraph_msgs/Clock``) for nodes running with ``use_sim_time``.
"""

from __future__ import annotations

import importlib
import logging
import math
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

from allo_mrad_ros.errors import BackendError
from rosbag_tools.bagio import BagReadError, open_bag

LOG = logging.getLogger("allo_bag.play")

DEFAULT_DELAY_S = 1.0
DEFAULT_WAIT_TIMEOUT_S = 30.0
ACK_TIMEOUT_S = 2.0


class PlayError(BackendError):
    """A bag cannot be played (bad option, no rclpy, unreadable bag)."""


@dataclass
class PlaySummary:
    """What :func:`play_bag` published.

    Attributes
    ----------
    published : dict
        Topic -> messages published (over all passes).
    skipped : dict
        Topic -> why it was not published.
    passes : int
        Complete passes over the bag.
    wall_s : float
        Seconds from the first message to the last.
    """

    published: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)
    passes: int = 0
    wall_s: float = 0.0


def import_message_class(msgtype: str) -> type:
    """Return the rclpy message class of ``pkg/msg/Name``.

    Raises
    ------
    ImportError
        If the package or the type is not installed.
    """
    package, kind, name = msgtype.split("/")
    module = importlib.import_module(f"{package}.{kind}")
    try:
        return getattr(module, name)
    except AttributeError:
        raise ImportError(f"{package}.{kind} has no type {name}") from None


def _qos_for(connection: Any, rclpy_qos: Any) -> Any:
    """The rclpy QoS of a publisher that offers what the recording offered."""
    profile = rclpy_qos.QoSProfile(depth=10)
    offered = getattr(connection.ext, "offered_qos_profiles", None) or []
    if offered:
        recorded = offered[0]
        profile.depth = max(1, int(recorded.depth or 10))
        if recorded.reliability.name == "BEST_EFFORT":
            profile.reliability = rclpy_qos.ReliabilityPolicy.BEST_EFFORT
        if recorded.durability.name == "TRANSIENT_LOCAL":
            profile.durability = rclpy_qos.DurabilityPolicy.TRANSIENT_LOCAL
    return profile


def _fields_match(cls: type, reader: Any, msgtype: str) -> bool:
    installed = list(cls.get_fields_and_field_types())
    recorded = [name for name, _ in reader.typestore.fielddefs[msgtype][1]]
    return installed == recorded


def play_bag(
    path: str | PathLike[str],
    *,
    rate: float = 1.0,
    loop: bool = False,
    topics: Iterable[str] | None = None,
    delay: float = DEFAULT_DELAY_S,
    clock: bool = False,
    node_name: str = "allo_bag_player",
    stop: threading.Event | None = None,
    passes: int | None = None,
    on_publish: Callable[[str, int], None] | None = None,
    wait_for: Iterable[str] = (),
    wait_timeout: float = DEFAULT_WAIT_TIMEOUT_S,
) -> PlaySummary:
    """Publish the messages of a bag with rclpy at the recorded pace.

    Parameters
    ----------
    path : path-like
        Bag folder or storage file.
    rate : float
        Playback speed multiple, positive (2 = twice as fast).
    loop : bool
        Start over at the end until ``stop`` is set (or ``passes`` are done).
    topics : iterable of str, optional
        Publish only these topics (default: all).
    delay : float
        Seconds to wait after creating the publishers, so subscribers can match them.
    clock : bool
        Also publish the bag time on ``/clock``.
    node_name : str
        Name of the player's node.
    stop : threading.Event, optional
        Set it to stop playback early.
    passes : int, optional
        Number of passes with ``loop`` (default: until stopped).
    on_publish : callable, optional
        Called with (topic, bag time) after every publish.
    wait_for : iterable of str
        Before the delay, wait until each of these topics has a matched subscriber (e.g.
        the detector's image topic), so nothing is published into the void. ``/clock``
        may be one of them when ``clock`` is set. Discovery is two-sided: the subscriber
        may match the publisher a little later and miss what comes before, so keep a
        ``delay`` (a few hundred ms) after the wait.
    wait_timeout : float
        Seconds to wait for those subscribers before giving up with :class:`PlayError`.

    Returns
    -------
    PlaySummary

    Raises
    ------
    PlayError
        For an invalid option, a missing rclpy, or a bag that cannot be read.
    """
    if not (isinstance(rate, (int, float)) and math.isfinite(rate) and rate > 0):
        raise PlayError(f"rate must be positive and finite, got {rate!r}")
    if not (math.isfinite(delay) and delay >= 0):
        raise PlayError(f"delay must be >= 0 seconds, got {delay!r}")
    if not (math.isfinite(wait_timeout) and wait_timeout >= 0):
        raise PlayError(f"wait_timeout must be >= 0 seconds, got {wait_timeout!r}")
    if passes is not None and passes < 1:
        raise PlayError(f"passes must be at least 1, got {passes!r}")
    try:
        import rclpy
        from rclpy import qos as rclpy_qos
        from rclpy.serialization import deserialize_message
        from rclpy.signals import SignalHandlerOptions
    except ImportError as error:
        raise PlayError(
            f"rclpy is not available ({error}); install ROS 2 or the PyPI wheels "
            "ros-rclpy and ros-rmw-fastrtps-cpp plus the message packages"
        ) from None
    total_passes = (passes or 0) if loop else 1
    stop = stop or threading.Event()
    summary = PlaySummary()
    context = rclpy.Context()
    # Python's own SIGINT (and the command's SIGTERM) handling stops the loop; rclpy's
    # handlers would only shut the context down and leave the loop publishing.
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = rclpy.create_node(node_name, context=context)
        try:
            with open_bag(path) as reader:
                _play(
                    reader,
                    node,
                    Path(path),
                    rclpy_qos,
                    deserialize_message,
                    rate=rate,
                    wanted=None if topics is None else set(topics),
                    delay=delay,
                    clock=clock,
                    total_passes=total_passes,
                    stop=stop,
                    summary=summary,
                    on_publish=on_publish,
                    wait_for=tuple(wait_for),
                    wait_timeout=wait_timeout,
                )
        finally:
            node.destroy_node()
    except BagReadError as error:
        raise PlayError(str(error)) from None
    finally:
        rclpy.shutdown(context=context)
    return summary


def _play(
    reader: Any,
    node: Any,
    path: Path,
    rclpy_qos: Any,
    deserialize_message: Callable,
    *,
    rate: float,
    wanted: set[str] | None,
    delay: float,
    clock: bool,
    total_passes: int,
    stop: threading.Event,
    summary: PlaySummary,
    on_publish: Callable[[str, int], None] | None,
    wait_for: tuple[str, ...],
    wait_timeout: float,
) -> None:
    if wanted is not None:
        missing = sorted(wanted - {c.topic for c in reader.connections})
        if missing:
            raise PlayError(f"{path}: no topic(s) {missing} in the bag")
    publishers: dict[int, Any] = {}
    classes: dict[int, type] = {}
    by_topic: dict[str, Any] = {}
    for connection in reader.connections:
        topic, msgtype = connection.topic, connection.msgtype
        if wanted is not None and topic not in wanted:
            continue
        if topic in summary.skipped:
            continue
        try:
            cls = import_message_class(msgtype)
        except (ImportError, ValueError) as error:
            reason = f"message type {msgtype} is not installed ({error})"
            summary.skipped[topic] = reason
            LOG.warning("skipping topic %s: %s", topic, reason)
            continue
        if not _fields_match(cls, reader, msgtype):
            reason = f"the installed {msgtype} differs from the bag's definition"
            summary.skipped[topic] = reason
            LOG.warning("skipping topic %s: %s", topic, reason)
            continue
        if topic not in by_topic:
            by_topic[topic] = node.create_publisher(cls, topic, _qos_for(connection, rclpy_qos))
            summary.published[topic] = 0
        publishers[connection.id] = by_topic[topic]
        classes[connection.id] = cls
    clock_publisher = None
    if clock:
        clock_publisher = node.create_publisher(
            import_message_class("rosgraph_msgs/msg/Clock"), "/clock", rclpy_qos.QoSProfile(depth=1)
        )
    connections = [c for c in reader.connections if c.id in publishers]
    if not connections:
        raise PlayError(f"{path}: nothing to play, every topic was skipped")
    waitable = dict(by_topic)
    if clock_publisher is not None:
        waitable["/clock"] = clock_publisher
    _wait_for_subscribers(waitable, wait_for, wait_timeout, stop, path)
    if stop.wait(delay):
        return
    checked: set[int] = set()
    start_wall = time.monotonic()
    done = 0
    while not stop.is_set() and (total_passes == 0 or done < total_passes):
        pass_start = time.monotonic()
        first_time = None
        last_clock = None
        for connection, timestamp, raw in reader.messages(connections=connections):
            first_time = timestamp if first_time is None else first_time
            due = pass_start + (timestamp - first_time) / 1e9 / rate
            wait = due - time.monotonic()
            if wait > 0 and stop.wait(wait):
                break
            data = bytes(raw)
            if connection.id not in checked:
                _check_decodes(connection, classes, data, deserialize_message, summary)
                checked.add(connection.id)
            if connection.topic in summary.skipped:
                continue
            if clock_publisher is not None and timestamp != last_clock:
                clock_publisher.publish(_clock_message(timestamp))
                last_clock = timestamp
            publishers[connection.id].publish(data)
            summary.published[connection.topic] += 1
            if on_publish is not None:
                on_publish(connection.topic, timestamp)
        else:
            done += 1
            summary.passes = done
            continue
        break
    summary.wall_s = time.monotonic() - start_wall
    for publisher in by_topic.values():
        # Reliable samples still in flight would be lost when the node goes away.
        if publisher.get_subscription_count():
            _wait_acked(publisher)


def _wait_for_subscribers(
    publishers: dict[str, Any],
    topics: tuple[str, ...],
    timeout: float,
    stop: threading.Event,
    path: Path,
) -> None:
    unknown = sorted(t for t in topics if t not in publishers)
    if unknown:
        raise PlayError(f"{path}: cannot wait for {unknown}: not published from this bag")
    deadline = time.monotonic() + timeout
    waiting = list(topics)
    while waiting and not stop.is_set():
        waiting = [t for t in waiting if publishers[t].get_subscription_count() == 0]
        if not waiting:
            return
        if time.monotonic() > deadline:
            raise PlayError(f"no subscriber on {waiting} within {timeout:g} s")
        stop.wait(0.02)


def _wait_acked(publisher: Any) -> None:
    from rclpy.duration import Duration

    try:
        publisher.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
    except Exception as error:  # best effort: some RMWs do not implement it
        LOG.debug("wait_for_all_acked failed on %s: %s", publisher.topic_name, error)


def _check_decodes(
    connection: Any,
    classes: dict[int, type],
    data: bytes,
    deserialize_message: Callable,
    summary: PlaySummary,
) -> None:
    try:
        deserialize_message(data, classes[connection.id])
    except Exception as error:  # rclpy raises several types for malformed CDR
        reason = f"its first message does not decode as the installed type ({error})"
        summary.skipped[connection.topic] = reason
        summary.published.pop(connection.topic, None)
        LOG.warning("skipping topic %s: %s", connection.topic, reason)


def _clock_message(timestamp: int) -> Any:
    from builtin_interfaces.msg import Time
    from rosgraph_msgs.msg import Clock

    return Clock(clock=Time(sec=timestamp // 10**9, nanosec=timestamp % 10**9))
