"""Benchmark of the running ``mrad_detector`` node at camera rates (``make bench-node``).

The node runs as its own process with its default parameters; a camera feed in this process
publishes rendered frames, poses and the sun with wall-clock stamps, subscribes to the
default outputs (``~/mask``, ``~/score``, ``~/overlay``, ``~/anomaly``) and records when each
mask arrives. For each camera mode (1920x1080 at 30 Hz, 1280x720 at 60 Hz) it reports the
frames processed per second and dropped, the latency from image stamp to received mask
(p50, p95, p99), the node's CPU seconds per processed frame and its resident memory after
100 and after 1,000 processed frames. ROS traffic stays on loopback
(``config/fastdds_loopback.xml``).

Usage: ``python -m allo_mrad_ros.benchmarks.node --frames 1000 --out reports/bench_node.json``;
``--serial`` runs the node with ``pipelined:=false`` (one thread, as before issue 15) and
``--compare-serial`` runs, per mode, the serial node and then the pipelined one back to back,
so both are measured under the same machine load.

``--compare-outputs`` measures instead the node's CPU seconds per frame with only ``~/mask``
subscribed against every output subscribed (score, overlay, reference and its camera_info,
result, regions, anomaly), in one run: blocks of frames alternate between the two, one
frame at a time (the next is published when the mask of the last arrived), so both see the
same machine load. CPU is the node process's user + system time over each block. It also
measures the node idle: every output unsubscribed while full-HD frames are published at 30 Hz
for ``--idle-seconds``, reported as percent of one core (target under 2 %: the node then
unsubscribes from the image, so no frame reaches it).
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
from allo_mrad_ros.camera import ALLO_INTRINSICS, CameraIntrinsics
from allo_mrad_ros.example_scene import paste_object
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render import ReferenceRenderer
from allo_mrad_ros.resources import share_path
from allo_mrad_ros.ros.feed import OUTPUT_TYPES, CameraFeed, start_node, stop_node
from allo_mrad_ros.ros.process_tuning import keep_freed_memory

SUN = (0.3, -0.5, 0.8)


# Camera modes measured: name -> (width, height, frame rate in Hz). The first is reported at
# the top level of the JSON report (the keys of earlier reports), the others under their name.
MODES = {"1080p30": (1920, 1080, 30.0), "720p60": (1280, 720, 60.0)}


def camera_of(width: int, height: int) -> CameraIntrinsics:
    """The ALLO camera's field of view at ``width`` x ``height``."""
    return ALLO_INTRINSICS.scaled(width / ALLO_INTRINSICS.width)


def _frames(camera: CameraIntrinsics = ALLO_INTRINSICS) -> tuple[np.ndarray, list[np.ndarray]]:
    pose = look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0])
    with ReferenceRenderer(None, camera, scale=1.0) as renderer:
        clean = renderer.render(pose, SUN).rgb
    with_object, _ = paste_object(clean, seed=1, centre=(0.5, 0.15), size=0.08)
    return pose, [clean, with_object]


@contextmanager
def _node_session(
    log_path: Path, feed_options: dict, *node_args: str, camera: CameraIntrinsics = ALLO_INTRINSICS
) -> Iterator[tuple[CameraFeed, psutil.Process]]:
    """Start the node and a camera feed on loopback DDS; stop both whatever happens."""
    os.environ.setdefault(
        "FASTDDS_DEFAULT_PROFILES_FILE", str(share_path("config", "fastdds_loopback.xml"))
    )
    # The feed stands for a camera driver and a viewer, C++ programs that reuse their
    # buffers; without this its Python receives would fault in pages the node competes for.
    keep_freed_memory(512)
    rclpy.init()
    feed = CameraFeed(camera, keep_messages=False, **feed_options)
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


def run(
    frames: int,
    rate_hz: float,
    log_path: Path,
    timeout_s: float,
    camera: CameraIntrinsics = ALLO_INTRINSICS,
    pipelined: bool = True,
    node_parameters: tuple[str, ...] = (),
) -> dict:
    """Drive the node at ``rate_hz`` until ``frames`` masks arrived; the report dictionary.

    ``node_parameters`` are extra ``name:=value`` parameters of the node.
    """
    pose, images = _frames(camera)
    node_args = (f"pipelined:={str(pipelined).lower()}", *node_parameters)
    with _node_session(log_path, {}, *node_args, camera=camera) as (feed, node):
        warm = time.time_ns()
        while not feed.arrival["mask"] and time.time_ns() - warm < 60e9:
            feed.publish_frame(time.time_ns(), images[0], pose, SUN)
            feed.spin(0.5)
        feed.arrival["mask"].clear()
        published: list[int] = []
        rss_mb: dict[int, float] = {}
        period = 1.0 / rate_hz
        cpu_before = node.cpu_times()
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
        cpu_after = node.cpu_times()
        feed.spin(1.0)
    arrivals = feed.arrival["mask"]
    stamps = sorted(arrivals)
    latencies = np.array([1e3 * (arrivals[s] - s / 1e9) for s in stamps])
    times = sorted(arrivals.values())
    fps = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 else 0.0
    cpu_s = (cpu_after.user - cpu_before.user) + (cpu_after.system - cpu_before.system)
    before, after = rss_mb.get(100), rss_mb.get(frames)
    return {
        "image": f"{camera.width}x{camera.height}",
        "input_rate_hz": rate_hz,
        "pipelined": pipelined,
        "node_parameters": list(node_parameters),
        "frames_published": len(published),
        "frames_processed": len(stamps),
        "frames_dropped": len(published) - len(stamps),
        "fps": fps,
        "latency_ms_p50": float(np.median(latencies)),
        "latency_ms_p95": float(np.percentile(latencies, 95)),
        "latency_ms_p99": float(np.percentile(latencies, 99)),
        "latency_ms_max": float(latencies.max()),
        "cpu_s_per_frame": cpu_s / max(len(stamps), 1),
        "rss_mb_after_100": before,
        "rss_mb_after_1000": after,
        "rss_frames_mark": frames,
        "rss_growth_percent": 100 * (after / before - 1) if before and after else None,
        "load_average_after": list(os.getloadavg()),
    }


def _summary_line(name: str, report: dict) -> str:
    growth = report["rss_growth_percent"]
    return (
        f"{name:8} {'pipelined' if report['pipelined'] else 'serial':9} "
        f"{report['fps']:6.2f} {report['frames_dropped']:4d}/{report['frames_published']:<5d} "
        f"{report['latency_ms_p50']:6.0f} {report['latency_ms_p95']:6.0f} "
        f"{report['latency_ms_p99']:6.0f} {report['cpu_s_per_frame']:7.3f} "
        f"{report['rss_mb_after_1000'] or float('nan'):7.0f} "
        f"{float('nan') if growth is None else growth:+6.1f}% "
        f"{report['load_average_after'][0]:5.2f}"
    )


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


def compare_outputs(rounds: int, block: int, log_path: Path, idle_seconds: float = 20.0) -> dict:
    """CPU seconds per frame of the node, mask only against every output, interleaved; then
    the node's CPU with nobody subscribed (:func:`idle_cpu_percent`)."""
    pose, images = _frames()
    cpu = {"mask_only": [], "every_output": []}
    options = {"outputs": ("mask",)}
    extra = ("publish_reference:=true", "publish_overlay:=true")
    idle: dict = {}
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
        if idle_seconds > 0:
            idle = idle_cpu_percent(feed, node, pose, images, idle_seconds)
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
        **idle,
    }


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=1000, help="processed frames to measure")
    parser.add_argument(
        "--modes",
        default=",".join(MODES),
        help=f"comma-separated camera modes of {list(MODES)}; the first goes to the top level",
    )
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per mode")
    parser.add_argument("--out", type=Path, default=Path("reports/bench_node.json"))
    parser.add_argument(
        "--serial", action="store_true", help="run the node with pipelined:=false only"
    )
    parser.add_argument(
        "--compare-serial",
        action="store_true",
        help="per mode, the serial node then the pipelined one, back to back",
    )
    parser.add_argument(
        "--compare-outputs",
        action="store_true",
        help="CPU per frame with only ~/mask subscribed against every output, interleaved",
    )
    parser.add_argument(
        "--node-param",
        action="append",
        default=[],
        metavar="NAME:=VALUE",
        help="a node parameter for the runs (repeatable), e.g. opencv_threads:=0",
    )
    parser.add_argument("--rounds", type=int, default=5, help="blocks per mode (compare)")
    parser.add_argument("--block", type=int, default=8, help="frames per block (compare)")
    parser.add_argument(
        "--idle-seconds",
        type=float,
        default=20.0,
        help="seconds of 30 Hz frames with no output subscribed (compare-outputs); 0: skip",
    )
    args = parser.parse_args(argv)
    log_dir = Path(tempfile.mkdtemp(prefix="bench_node_"))
    if args.compare_outputs:
        log = log_dir / "node.log"
        report = compare_outputs(args.rounds, args.block, log, args.idle_seconds)
        if "idle_cpu_percent_of_one_core" in report:
            print(
                f"nobody subscribed, {report['idle_rate_hz']:.1f} Hz of full-HD frames for "
                f"{report['idle_seconds']:.0f} s: node CPU "
                f"{report['idle_cpu_percent_of_one_core']:.2f} % of one core"
            )
        print(
            f"mrad_detector at {report['image']}, CPU seconds per frame (node process, "
            f"median of {args.rounds} interleaved blocks of {args.block} frames each)\n"
            f"only ~/mask subscribed: {report['cpu_s_per_frame_mask_only']:.3f} s\n"
            f"every output subscribed: {report['cpu_s_per_frame_every_output']:.3f} s\n"
            f"saving: {report['saving_percent']:.1f} %\nnode log: {log}"
        )
        return finish(args.out, report)
    modes = [name.strip() for name in args.modes.split(",") if name.strip()]
    unknown = sorted(set(modes) - set(MODES))
    if unknown or not modes:
        parser.error(f"unknown mode(s) {unknown or modes}; choose from {list(MODES)}")
    bad = [text for text in args.node_param if ":=" not in text]
    if bad:
        parser.error(f"--node-param needs NAME:=VALUE, got {bad}")
    variants = [False, True] if args.compare_serial else [not args.serial]
    results: dict[tuple[str, bool], dict] = {}
    print(
        f"mrad_detector, {' '.join(args.node_param) or 'default parameters'}; outputs mask, "
        f"score, overlay; "
        f"{args.frames} frames per run, {os.cpu_count()} CPUs\n"
        f"{'mode':8} {'worker':9} {'fps':>6} {'dropped':>10} {'p50':>6} {'p95':>6} {'p99':>6} "
        f"{'cpu s/f':>7} {'RSS MB':>7} {'growth':>7} {'load':>5}"
    )
    for name in modes:
        width, height, rate = MODES[name]
        for pipelined in variants:
            log = log_dir / f"node_{name}_{'pipelined' if pipelined else 'serial'}.log"
            camera = camera_of(width, height)
            parameters = tuple(args.node_param)
            report = run(args.frames, rate, log, args.timeout, camera, pipelined, parameters)
            results[name, pipelined] = report
            print(_summary_line(name, report), flush=True)
    first, main_variant = modes[0], variants[-1]
    combined = dict(results[first, main_variant])
    for name in modes[1:]:
        combined[name] = results[name, main_variant]
    if args.compare_serial:
        combined["serial"] = {name: results[name, False] for name in modes}
    print(f"node logs: {log_dir}")
    return finish(args.out, combined)


if __name__ == "__main__":
    sys.exit(main())
