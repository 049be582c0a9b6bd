"""Benchmark of the running ``mrad_detector`` node at 1920x1080 (``make bench-node``).

The node runs as its own process with its default parameters; a
camera feed in this process publishes rendered full-HD frames, poses and the sun at
``--rate`` Hz with wall-clock stamps, and records when each mask arrives. Reports the
sustained output rate, the latency from image stamp to received mask, and the node's
resident memory after 100 and after 1,000 processed frames. ROS traffic stays on loopback
(``config/fastdds_loopback.xml``).

Usage: ``python -m allo_mrad_ros.benchmarks.node --frames 1000 --out reports/bench_node.json``

``--compare-outputs`` measures instead the node's CPU seconds per frame with only ``~/mask``
subscribed against every output subscribed (score, overlay, reference and its camera_info,
result, regions, anomaly), in one run: blocks of frames alternate between the two, one
frame at a time (the next is published when the mask of the last arrived), so both see the
same machine load. CPU is the node process's user + system time over each block.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import psutil
import rclpy

from allo_mrad_ros.benchmarks import finish
from allo_mrad_ros.camera import ALLO_INTRINSICS
from allo_mrad_ros.example_scene import paste_object
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render import ReferenceRenderer
from allo_mrad_ros.resources import share_path
from allo_mrad_ros.ros.feed import OUTPUT_TYPES, CameraFeed, start_node, stop_node

SUN = (0.3, -0.5, 0.8)


def _frames() -> tuple[np.ndarray, list[np.ndarray]]:
    pose = look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0])
    with ReferenceRenderer(None, ALLO_INTRINSICS, scale=1.0) as camera:
        clean = camera.render(pose, SUN).rgb
    with_object, _ = paste_object(clean, seed=1, centre=(0.5, 0.15), size=0.08)
    return pose, [clean, with_object]


@contextmanager
def _node_session(
    log_path: Path, feed_options: dict, *node_args: str
) -> Iterator[tuple[CameraFeed, psutil.Process]]:
    """Start the node and a camera feed on loopback DDS; stop both whatever happens."""
    os.environ.setdefault(
        "FASTDDS_DEFAULT_PROFILES_FILE", str(share_path("config", "fastdds_loopback.xml"))
    )
    rclpy.init()
    feed = CameraFeed(ALLO_INTRINSICS, keep_messages=False, **feed_options)
    process = start_node(log_path, *node_args)
    try:
        if not feed.wait_for_node(60.0):
            raise RuntimeError(f"node did not subscribe; see {log_path}")
        yield feed, psutil.Process(process.pid)
        if process.poll() is not None:
            raise RuntimeError(f"node exited with {process.returncode}; see {log_path}")
    finally:
        stop_node(process)
        feed.node.destroy_node()
        rclpy.shutdown()


def run(frames: int, rate_hz: float, log_path: Path, timeout_s: float) -> dict:
    """Drive the node and measure; returns the report dictionary."""
    pose, images = _frames()
    with _node_session(log_path, {}) as (feed, node):
        warm = time.time_ns()
        while not feed.arrival["mask"] and time.time_ns() - warm < 60e9:
            feed.publish_frame(time.time_ns(), images[0], pose, SUN)
            feed.spin(0.5)
        feed.arrival["mask"].clear()
        published: list[int] = []
        rss_mb: dict[int, float] = {}
        period = 1.0 / rate_hz
        start = time.monotonic()
        next_time = start
        while len(feed.arrival["mask"]) < frames and time.monotonic() - start < timeout_s:
            if time.monotonic() >= next_time:
                stamp = time.time_ns()
                feed.publish_frame(stamp, images[len(published) % 2], pose, SUN)
                published.append(stamp)
                next_time += period
            rclpy.spin_once(feed.node, timeout_sec=0.002)
            done = len(feed.arrival["mask"])
            for mark in (100, frames):
                if done >= mark and mark not in rss_mb:
                    rss_mb[mark] = node.memory_info().rss / 2**20
        feed.spin(1.0)
    arrivals = feed.arrival["mask"]
    stamps = sorted(arrivals)
    latencies = np.array([1e3 * (arrivals[s] - s / 1e9) for s in stamps])
    times = sorted(arrivals.values())
    fps = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 else 0.0
    return {
        "image": f"{ALLO_INTRINSICS.width}x{ALLO_INTRINSICS.height}",
        "input_rate_hz": rate_hz,
        "frames_published": len(published),
        "frames_processed": len(stamps),
        "frames_dropped": len(published) - len(stamps),
        "fps": fps,
        "latency_ms_p50": float(np.median(latencies)),
        "latency_ms_p95": float(np.percentile(latencies, 95)),
        "latency_ms_max": float(latencies.max()),
        "rss_mb_after_100": rss_mb.get(100),
        "rss_mb_after_1000": rss_mb.get(frames),
        "rss_frames_mark": frames,
    }


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


def compare_outputs(rounds: int, block: int, log_path: Path) -> dict:
    """CPU seconds per frame of the node, mask only against every output, interleaved."""
    pose, images = _frames()
    cpu = {"mask_only": [], "every_output": []}
    options = {"outputs": ("mask",)}
    extra = ("publish_reference:=true", "publish_overlay:=true")
    with _node_session(log_path, options, *extra) as (feed, node):
        for index in range(2 * rounds):
            mode = "every_output" if index % 2 else "mask_only"
            feed.set_outputs(OUTPUT_TYPES if mode == "every_output" else ())
            feed.spin(2.0)  # discovery of the (un)subscriptions
            _lock_step(feed, pose, images, 2)  # settle
            before = node.cpu_times()
            count = _lock_step(feed, pose, images, block)
            after = node.cpu_times()
            seconds = (after.user - before.user) + (after.system - before.system)
            cpu[mode].append(seconds / max(count, 1))
    mask_only = float(np.median(cpu["mask_only"]))
    every = float(np.median(cpu["every_output"]))
    return {
        "image": f"{ALLO_INTRINSICS.width}x{ALLO_INTRINSICS.height}",
        "rounds": rounds,
        "frames_per_block": block,
        "cpu_s_per_frame_mask_only_blocks": cpu["mask_only"],
        "cpu_s_per_frame_every_output_blocks": cpu["every_output"],
        "cpu_s_per_frame_mask_only": mask_only,
        "cpu_s_per_frame_every_output": every,
        "saving_percent": 100.0 * (1.0 - mask_only / every),
    }


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=1000, help="processed frames to measure")
    parser.add_argument("--rate", type=float, default=10.0, help="input frame rate, Hz")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds")
    parser.add_argument("--out", type=Path, default=Path("reports/bench_node.json"))
    parser.add_argument(
        "--compare-outputs",
        action="store_true",
        help="CPU per frame with only ~/mask subscribed against every output, interleaved",
    )
    parser.add_argument("--rounds", type=int, default=5, help="blocks per mode (compare)")
    parser.add_argument("--block", type=int, default=8, help="frames per block (compare)")
    args = parser.parse_args(argv)
    log = Path(tempfile.mkdtemp(prefix="bench_node_")) / "node.log"
    if args.compare_outputs:
        report = compare_outputs(args.rounds, args.block, log)
        print(
            f"mrad_detector at {report['image']}, CPU seconds per frame (node process, "
            f"median of {args.rounds} interleaved blocks of {args.block} frames each)\n"
            f"only ~/mask subscribed: {report['cpu_s_per_frame_mask_only']:.3f} s\n"
            f"every output subscribed: {report['cpu_s_per_frame_every_output']:.3f} s\n"
            f"saving: {report['saving_percent']:.1f} %\nnode log: {log}"
        )
        return finish(args.out, report)
    report = run(args.frames, args.rate, log, args.timeout)
    growth = (
        100 * (report["rss_mb_after_1000"] / report["rss_mb_after_100"] - 1)
        if report["rss_mb_after_1000"] and report["rss_mb_after_100"]
        else float("nan")
    )
    report["rss_growth_percent"] = growth
    print(
        f"mrad_detector at {report['image']}, input {args.rate:g} Hz, default parameters\n"
        f"frames published {report['frames_published']}, processed {report['frames_processed']}, "
        f"dropped as stale {report['frames_dropped']}\n"
        f"sustained output rate: {report['fps']:.2f} frames/s\n"
        f"latency image stamp -> mask received: p50 {report['latency_ms_p50']:.0f} ms, "
        f"p95 {report['latency_ms_p95']:.0f} ms, max {report['latency_ms_max']:.0f} ms\n"
        f"node resident memory: {report['rss_mb_after_100']:.0f} MB after 100 frames, "
        f"{report['rss_mb_after_1000']:.0f} MB after {args.frames} ({growth:+.1f} %)\n"
        f"node log: {log}"
    )
    return finish(args.out, report)


if __name__ == "__main__":
    sys.exit(main())
