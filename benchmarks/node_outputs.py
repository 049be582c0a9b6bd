"""The node's CPU per output (``bench-node --compare-outputs``, ``make bench-node-outputs``).

``python -m benchmarks.node --compare-outputs`` measures what each output
costs: the node's CPU seconds per frame with only ``~/mask`` subscribed (the base), with the
base plus one output (``~/score`` at the processing resolution with its camera_info; the
same with ``score_full_resolution``; ``~/overlay``; ``~/reference`` with its camera_info;
``~/result``, ``~/regions`` and, where vision_msgs is installed, ``~/detections``) and with
every output, in one run: blocks of frames cycle through these subscriptions, one frame at a
time (the next is published when the mask of the last arrived), so all see the same machine
load. An output's cost is the median over rounds of its block's CPU per frame less the base
block's of the same round. CPU is the node process's user + system time over each block. It
also measures the node idle: every output unsubscribed while full-HD frames are published at
30 Hz for ``--idle-seconds``, reported as percent of one core (target under 2 %: the node
then unsubscribes from the image, so no frame reaches it).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import psutil
import rclpy
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters

from allo_mrad_ros import interface
from allo_mrad_ros.camera import ALLO_INTRINSICS
from allo_mrad_ros.ros.outputs import vision_msgs_module
from benchmarks.node_session import SUN, node_session, still_frames
from harness.feed import OUTPUT_TYPES, CameraFeed


def _lock_step(feed: CameraFeed, pose: np.ndarray, images: list, frames: int) -> int:
    """Publish ``frames`` frames, each after the mask of the previous one; return the count."""
    done = 0
    for index in range(frames):
        stamp = time.time_ns()
        end = time.monotonic() + 60.0
        while stamp not in feed.arrival["mask"] and time.monotonic() < end:
            feed.publish_frame(stamp, images[index % 2], pose, SUN)
            feed.wait_for(lambda s=stamp: s in feed.arrival["mask"], 10.0)
        done += stamp in feed.arrival["mask"]
    return done


def idle_cpu_percent(
    feed: CameraFeed,
    node: psutil.Process,
    pose: np.ndarray,
    images: list,
    seconds: float,
    rate_hz: float = 30.0,
) -> dict:
    """The node's CPU (percent of one core) while frames are published at ``rate_hz`` for
    ``seconds`` and nobody subscribes to any of its outputs."""
    for topic in list(feed.subscriptions):
        feed.unsubscribe(topic)
    unsubscribed = feed.wait_for(lambda: feed.pub_image.get_subscription_count() == 0, 30.0)
    feed.spin(1.0)
    before, start = node.cpu_times(), time.monotonic()
    published = 0
    while time.monotonic() - start < seconds:
        feed.publish_frame(time.time_ns(), images[published % 2], pose, SUN)
        published += 1
        feed.spin(max(0.0, start + published / rate_hz - time.monotonic()))
    after, elapsed = node.cpu_times(), time.monotonic() - start
    used = (after.user - before.user) + (after.system - before.system)
    return {
        "idle_seconds": elapsed,
        "idle_frames_published": published,
        "idle_rate_hz": published / elapsed,
        "idle_node_unsubscribed_from_image": unsubscribed,
        "idle_cpu_percent_of_one_core": 100.0 * used / elapsed,
    }


# The subscriptions --compare-outputs cycles through: name -> (outputs besides ~/mask,
# score_full_resolution). The base first; an output's cost is its block's CPU less the base's.
OUTPUT_SETS: dict[str, tuple[tuple[str, ...], bool]] = {
    "mask_only": ((), False),
    "score": (("score", "score/camera_info"), False),
    "score_full_resolution": (("score", "score/camera_info"), True),
    "overlay": (("overlay",), False),
    "reference": (("reference", "reference/camera_info"), False),
    "result_regions_detections": (("result", "regions", "detections"), False),
    "every_output": ((*OUTPUT_TYPES, "detections"), False),
}


def _set_score_full_resolution(feed: CameraFeed, value: bool) -> bool:
    """Set the node's ``score_full_resolution`` through its parameter service; whether the
    node accepted it."""
    client = feed.node.create_client(SetParameters, f"/{interface.NODE_NAME}/set_parameters")
    try:
        if not client.wait_for_service(timeout_sec=10.0):
            return False
        request = SetParameters.Request()
        request.parameters = [
            Parameter(
                name="score_full_resolution",
                value=ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=value),
            )
        ]
        future = client.call_async(request)
        rclpy.spin_until_future_complete(feed.node, future, timeout_sec=10.0)
        response = future.result()
        return bool(response and response.results and response.results[0].successful)
    finally:
        feed.node.destroy_client(client)


def _subscribe_set(feed: CameraFeed, outputs: tuple[str, ...]) -> None:
    """Subscribe to ``~/mask`` and ``outputs`` only (``detections`` where vision_msgs is)."""
    vision = vision_msgs_module()
    wanted = {"mask", *(name for name in outputs if name != "detections")}
    for topic in list(feed.subscriptions):
        if topic not in wanted and topic != "detections":
            feed.unsubscribe(topic)
    for topic in sorted(wanted):
        feed.subscribe(topic, OUTPUT_TYPES[topic])
    if vision is not None and "detections" in outputs:
        feed.subscribe("detections", vision.Detection2DArray)
    elif "detections" in feed.subscriptions:
        feed.unsubscribe("detections")


def compare_outputs(rounds: int, block: int, log_path: Path, idle_seconds: float = 20.0) -> dict:
    """CPU seconds per frame of the node for each of :data:`OUTPUT_SETS`, interleaved; then
    the node's CPU with nobody subscribed (:func:`idle_cpu_percent`)."""
    pose, images = still_frames()
    cpu: dict[str, list[float]] = {name: [] for name in OUTPUT_SETS}
    options = {"outputs": ("mask",)}
    extra = ("publish_reference:=true", "publish_overlay:=true")
    idle: dict = {}
    full_resolution = False
    with node_session(log_path, options, *extra) as (feed, node):
        for _ in range(rounds):
            for name, (outputs, full) in OUTPUT_SETS.items():
                if full != full_resolution:
                    if not _set_score_full_resolution(feed, full):
                        raise RuntimeError(f"the node refused score_full_resolution:={full}")
                    full_resolution = full
                _subscribe_set(feed, outputs)
                feed.spin(2.0)  # discovery of the (un)subscriptions
                _lock_step(feed, pose, images, 2)  # settle
                before = node.cpu_times()
                count = _lock_step(feed, pose, images, block)
                after = node.cpu_times()
                seconds = (after.user - before.user) + (after.system - before.system)
                cpu[name].append(seconds / max(count, 1))
        if idle_seconds > 0:
            idle = idle_cpu_percent(feed, node, pose, images, idle_seconds)
    median = {name: float(np.median(values)) for name, values in cpu.items()}
    added = {
        name: float(np.median(np.subtract(values, cpu["mask_only"])))
        for name, values in cpu.items()
        if name != "mask_only"
    }
    return {
        "image": f"{ALLO_INTRINSICS.width}x{ALLO_INTRINSICS.height}",
        "rounds": rounds,
        "frames_per_block": block,
        "detections_measured": vision_msgs_module() is not None,
        "cpu_s_per_frame_blocks": cpu,
        "cpu_s_per_frame": median,
        "cpu_s_per_frame_added": added,
        # The keys of earlier reports.
        "cpu_s_per_frame_mask_only": median["mask_only"],
        "cpu_s_per_frame_every_output": median["every_output"],
        "saving_percent": 100.0 * (1.0 - median["mask_only"] / median["every_output"]),
        "load_average_after": list(os.getloadavg()),
        **idle,
    }


OUTPUT_LABELS = {
    "mask_only": "~/mask, ~/anomaly (the base)",
    "score": "+ ~/score, processing resolution, + camera_info",
    "score_full_resolution": "+ ~/score, full resolution, + camera_info",
    "overlay": "+ ~/overlay",
    "reference": "+ ~/reference + camera_info",
    "result_regions_detections": "+ ~/result, ~/regions, ~/detections",
    "every_output": "every output (score at processing resolution)",
}


def outputs_table(report: dict) -> str:
    lines = [f"{'outputs subscribed':50} {'cpu s/f':>8} {'added':>8}"]
    for name, label in OUTPUT_LABELS.items():
        if name == "result_regions_detections" and not report["detections_measured"]:
            label = "+ ~/result, ~/regions (no vision_msgs here)"
        added = report["cpu_s_per_frame_added"].get(name)
        lines.append(
            f"{label:50} {report['cpu_s_per_frame'][name]:8.4f} "
            f"{'' if added is None else f'{added:+8.4f}':>8}"
        )
    return "\n".join(lines)
