"""Benchmark of the running ``mrad_detector`` node at camera rates (``make bench-node``).

The node runs as its own process with its default parameters; a camera feed in this process
publishes rendered frames, poses and the sun with wall-clock stamps, subscribes to the
default outputs (``~/mask``, ``~/score``, ``~/overlay``, ``~/anomaly``) and records when each
mask arrives. The camera moves as an arm moves it (``--trajectory moving``: a smooth sweep
around the station at up to 0.3 m/s and 5 deg/s, :mod:`.trajectory`) or stays still
(``still``); each published image is the render of the pose published with it, rendered
ahead (3 s of path, played back and forth), and every other image has a pasted object. For
each trajectory and camera mode (1920x1080 at 30 Hz, 1280x720 at 60 Hz) it reports the
frames processed per second and dropped, the references the node rendered per processed
frame (from the ``references_rendered`` and ``frames_processed`` counters of
``/diagnostics``; n/a for a node without the first), the latency from image stamp to
received mask (p50, p95, p99), the node's CPU seconds per processed frame (and under it each
kind of thread's share, :mod:`.thread_cpu`) and its resident memory after 100 and after
1,000 processed frames. ROS traffic stays on loopback
(``config/fastdds_loopback.xml``).

Usage: ``python -m benchmarks.node --frames 1000 --out reports/bench_node.json``;
``--serial`` runs the node with ``pipelined:=false`` (one thread) and
``--compare-serial`` runs, per mode, the serial node and then the pipelined one back to back,
so both are measured under the same machine load.

``--compare-outputs`` measures instead what each output costs (:mod:`.node_outputs`); both
start the node and the feed with :func:`.node_session.node_session`.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rclpy

from allo_mrad_ros.camera import ALLO_INTRINSICS, CameraIntrinsics
from allo_mrad_ros.example_scene import paste_object
from allo_mrad_ros.render import ReferenceRenderer
from benchmarks import add_names_option, finish, thread_cpu
from benchmarks.node_outputs import compare_outputs, outputs_table
from benchmarks.node_session import SUN, node_session, still_frames
from benchmarks.trajectory import (
    MAX_ANGULAR_DEG_S,
    MAX_LINEAR_M_S,
    SEGMENT_S,
    TRAJECTORIES,
    ping_pong,
    segment_poses,
    speeds,
)
from harness.feed import CameraFeed

# Camera modes measured: name -> (width, height, frame rate in Hz). The first is reported at
# the top level of the JSON report (the keys of earlier reports), the others under their name.
MODES = {"1080p30": (1920, 1080, 30.0), "720p60": (1280, 720, 60.0)}


def camera_of(width: int, height: int) -> CameraIntrinsics:
    """The ALLO camera's field of view at ``width`` x ``height``."""
    return ALLO_INTRINSICS.scaled(width / ALLO_INTRINSICS.width)


@dataclass(frozen=True)
class FeedPlan:
    """What the feed publishes: the ``index``-th frame is ``images[frame(index)]`` with
    ``poses[frame(index)]``, a render of that pose (odd frames with a pasted object)."""

    trajectory: str
    poses: list[np.ndarray]
    images: list[np.ndarray]
    rate_hz: float

    def frame(self, index: int) -> int:
        """The segment frame published as the ``index``-th: played back and forth when
        moving; still, the clean and the object image in turn."""
        if self.trajectory == "still":
            return index % 2
        return ping_pong(index, len(self.poses))

    def motion(self) -> dict:
        """The played path's largest and mean speeds (zero when still)."""
        linear, angular = speeds(self.poses, self.rate_hz)
        return {
            "trajectory": self.trajectory,
            "segment_frames": len(self.images),
            "segment_s": (len(self.poses) - 1) / self.rate_hz,
            "linear_m_s_max": float(linear.max()),
            "linear_m_s_mean": float(linear.mean()),
            "angular_deg_s_max": float(angular.max()),
            "angular_deg_s_mean": float(angular.mean()),
            "feed_images_mb": sum(image.nbytes for image in self.images) / 2**20,
        }


def plan_feed(trajectory: str, rate_hz: float, camera: CameraIntrinsics) -> FeedPlan:
    """Render the frames of ``trajectory`` at ``rate_hz`` ahead: one segment of the moving
    path (``SEGMENT_S`` seconds, about 0.55 GB at 1080p30 or 720p60), or the still pose's
    clean and object images.

    Rendered in this process before the node starts: rendering full-HD images at the
    camera's rate as they are published would be too slow, and decoding compressed ones
    would compete with the node for the two cores.
    """
    if trajectory == "still":
        pose, images = still_frames(camera)
        return FeedPlan(trajectory, [pose, pose], images, rate_hz)
    poses = segment_poses(trajectory, rate_hz, SEGMENT_S)
    images = []
    with ReferenceRenderer(None, camera, scale=1.0) as renderer:
        for index, pose in enumerate(poses):
            image = renderer.render(pose, SUN).rgb
            if index % 2:  # every other frame, as the still feed: the object comes and goes
                image, _ = paste_object(image, seed=1, centre=(0.5, 0.15), size=0.08)
            images.append(image)
    return FeedPlan(trajectory, poses, images, rate_hz)


def _counters(feed: CameraFeed) -> dict[str, int]:
    """The node's cumulative counters of the latest ``/diagnostics`` pipeline status."""
    counters = {}
    for key in ("frames_processed", "references_rendered", "references_reused"):
        value = feed.diagnostic_values().get(key)
        if value is not None and value.isdigit():
            counters[key] = int(value)
    return counters


def _fresh_counters(feed: CameraFeed, seconds: float = 2.5) -> dict[str, int]:
    """Counters from a ``/diagnostics`` message published after this call (the node
    publishes one a second), so they include every frame it processed before."""
    feed.diagnostics.clear()
    feed.wait_for(lambda: len(feed.diagnostics) >= 2, seconds)
    return _counters(feed)


def renders_per_frame(before: dict[str, int], after: dict[str, int]) -> float | None:
    """References rendered per processed frame between two counter readings (None when the
    node does not count its renders or processed nothing)."""
    keys = ("references_rendered", "frames_processed")
    if not all(key in before and key in after for key in keys):
        return None
    processed = after["frames_processed"] - before["frames_processed"]
    if processed <= 0:
        return None
    return (after["references_rendered"] - before["references_rendered"]) / processed


def run(
    frames: int,
    rate_hz: float,
    log_path: Path,
    timeout_s: float,
    camera: CameraIntrinsics = ALLO_INTRINSICS,
    pipelined: bool = True,
    node_parameters: tuple[str, ...] = (),
    trajectory: str = "moving",
    plan: FeedPlan | None = None,
) -> dict:
    """Drive the node at ``rate_hz`` until ``frames`` masks arrived; the report dictionary.

    ``node_parameters`` are extra ``name:=value`` parameters of the node; ``trajectory``
    one of :data:`~.trajectory.TRAJECTORIES` (``plan``: its frames, rendered already).
    """
    plan = plan or plan_feed(trajectory, rate_hz, camera)
    node_args = (f"pipelined:={str(pipelined).lower()}", *node_parameters)
    load_before = list(os.getloadavg())
    with node_session(log_path, {}, *node_args, camera=camera) as (feed, node):
        warm = time.time_ns()
        while not feed.arrival["mask"] and time.time_ns() - warm < 60e9:
            feed.publish_frame(time.time_ns(), plan.images[0], plan.poses[0], SUN)
            feed.spin(0.5)
        counters_before = _fresh_counters(feed)
        feed.arrival["mask"].clear()
        published: list[int] = []
        rss_mb: dict[int, float] = {}
        period = 1.0 / rate_hz
        cpu_before, threads_before = node.cpu_times(), thread_cpu.sample(node.pid)
        start = time.monotonic()
        next_time = start
        while len(feed.arrival["mask"]) < frames and time.monotonic() - start < timeout_s:
            if time.monotonic() >= next_time:
                stamp = time.time_ns()
                index = plan.frame(len(published))
                feed.publish_frame(stamp, plan.images[index], plan.poses[index], SUN)
                published.append(stamp)
                next_time += period
            rclpy.spin_once(feed.node, timeout_sec=0.002)
            done = len(feed.arrival["mask"])
            for mark in (100, frames):
                if done >= mark and mark not in rss_mb:
                    rss_mb[mark] = node.memory_info().rss / 2**20
        cpu_after, threads_after = node.cpu_times(), thread_cpu.sample(node.pid)
        feed.spin(1.0)
        counters_after = _fresh_counters(feed)
    arrivals = feed.arrival["mask"]
    stamps = sorted(arrivals)
    latencies = np.array([1e3 * (arrivals[s] - s / 1e9) for s in stamps])
    times = sorted(arrivals.values())
    fps = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 else 0.0
    cpu_s = (cpu_after.user - cpu_before.user) + (cpu_after.system - cpu_before.system)
    before, after = rss_mb.get(100), rss_mb.get(frames)
    reused = [c.get("references_reused") for c in (counters_before, counters_after)]
    return {
        "image": f"{camera.width}x{camera.height}",
        "input_rate_hz": rate_hz,
        "pipelined": pipelined,
        "node_parameters": list(node_parameters),
        **plan.motion(),
        "frames_published": len(published),
        "frames_processed": len(stamps),
        "frames_dropped": len(published) - len(stamps),
        "fps": fps,
        "renders_per_frame": renders_per_frame(counters_before, counters_after),
        "references_reused": None if None in reused else reused[1] - reused[0],
        "node_counters_before": counters_before,
        "node_counters_after": counters_after,
        "latency_ms_p50": float(np.median(latencies)),
        "latency_ms_p95": float(np.percentile(latencies, 95)),
        "latency_ms_p99": float(np.percentile(latencies, 99)),
        "latency_ms_max": float(latencies.max()),
        "cpu_s_per_frame": cpu_s / max(len(stamps), 1),
        "thread_cpu_ms_per_frame": thread_cpu.per_frame_ms(
            threads_before, threads_after, len(stamps)
        ),
        "rss_mb_after_100": before,
        "rss_mb_after_1000": after,
        "rss_frames_mark": frames,
        "rss_growth_percent": 100 * (after / before - 1) if before and after else None,
        "load_average_before": load_before,
        "load_average_after": list(os.getloadavg()),
    }


SUMMARY_HEADER = (
    f"{'mode':8} {'path':6} {'worker':9} {'fps':>6} {'dropped':>10} {'rend/f':>6} "
    f"{'p50':>6} {'p95':>6} {'p99':>6} {'cpu s/f':>7} {'RSS MB':>7} {'growth':>7} {'load':>9}"
)


def summary_line(name: str, report: dict) -> str:
    """One run's row under :data:`SUMMARY_HEADER`."""
    growth = report["rss_growth_percent"]
    renders = report.get("renders_per_frame")
    return (
        f"{name:8} {report.get('trajectory', 'still'):6} "
        f"{'pipelined' if report['pipelined'] else 'serial':9} "
        f"{report['fps']:6.2f} {report['frames_dropped']:4d}/{report['frames_published']:<5d} "
        f"{'n/a' if renders is None else f'{renders:.2f}':>6} "
        f"{report['latency_ms_p50']:6.0f} {report['latency_ms_p95']:6.0f} "
        f"{report['latency_ms_p99']:6.0f} {report['cpu_s_per_frame']:7.3f} "
        f"{report['rss_mb_after_1000'] or float('nan'):7.0f} "
        f"{float('nan') if growth is None else growth:+6.1f}% "
        f"{report['load_average_before'][0]:4.2f}-{report['load_average_after'][0]:4.2f}"
    )


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=1000, help="processed frames to measure")
    add_names_option(
        parser, "--modes", MODES, what="mode", help="camera modes; the first goes to the top level"
    )
    add_names_option(
        parser,
        "--trajectory",
        TRAJECTORIES,
        what="trajectory",
        help=f"camera paths (moving: up to {MAX_LINEAR_M_S} m/s and {MAX_ANGULAR_DEG_S} "
        "deg/s); the first goes to the top level",
    )
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per run")
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
        help="CPU per frame of ~/mask alone, plus each output, and every output, interleaved",
    )
    parser.add_argument(
        "--node-param",
        action="append",
        default=[],
        metavar="NAME:=VALUE",
        help="a node parameter for the runs (repeatable), e.g. opencv_threads:=0",
    )
    parser.add_argument("--rounds", type=int, default=5, help="blocks per output set (compare)")
    parser.add_argument("--block", type=int, default=16, help="frames per block (compare)")
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
        load = os.getloadavg()[0]
        report = compare_outputs(args.rounds, args.block, log, args.idle_seconds)
        report["load_average_before"] = load
        if "idle_cpu_percent_of_one_core" in report:
            print(
                f"nobody subscribed, {report['idle_rate_hz']:.1f} Hz of full-HD frames for "
                f"{report['idle_seconds']:.0f} s: node CPU "
                f"{report['idle_cpu_percent_of_one_core']:.2f} % of one core"
            )
        print(
            f"mrad_detector at {report['image']}, CPU seconds per frame (node process, "
            f"median of {args.rounds} interleaved blocks of {args.block} frames each; added: "
            f"median over rounds of the block less the base block of its round); load "
            f"{load:.2f}-{report['load_average_after'][0]:.2f}\n"
            f"{outputs_table(report)}\n"
            f"every output against the base: {report['saving_percent']:.1f} % saved\n"
            f"node log: {log}"
        )
        return finish(args.out, report)
    modes, paths = args.modes, args.trajectory
    bad = [text for text in args.node_param if ":=" not in text]
    if bad:
        parser.error(f"--node-param needs NAME:=VALUE, got {bad}")
    variants = [False, True] if args.compare_serial else [not args.serial]
    results: dict[tuple[str, str, bool], dict] = {}
    print(
        f"mrad_detector, {' '.join(args.node_param) or 'default parameters'}; outputs mask, "
        f"score, overlay; {args.frames} frames per run, {os.cpu_count()} CPUs; rend/f: "
        f"references rendered per processed frame (/diagnostics)\n{SUMMARY_HEADER}",
        flush=True,
    )
    for trajectory in paths:
        for name in modes:
            width, height, rate = MODES[name]
            camera = camera_of(width, height)
            plan = plan_feed(trajectory, rate, camera)  # rendered once for both workers
            for pipelined in variants:
                log = (
                    log_dir
                    / f"node_{name}_{trajectory}_{'pipelined' if pipelined else 'serial'}.log"
                )
                parameters = tuple(args.node_param)
                report = run(
                    args.frames, rate, log, args.timeout, camera, pipelined, parameters, plan=plan
                )
                results[name, trajectory, pipelined] = report
                print(summary_line(name, report), flush=True)
                print(thread_cpu.summary(report.get("thread_cpu_ms_per_frame")), flush=True)
            del plan
    first, main_variant = modes[0], variants[-1]
    main_path = paths[0]
    combined = dict(results[first, main_path, main_variant])
    for name in modes[1:]:
        combined[name] = results[name, main_path, main_variant]
    combined["trajectories"] = {
        path: {name: results[name, path, main_variant] for name in modes} for path in paths
    }
    if args.compare_serial:
        combined["serial"] = {
            path: {name: results[name, path, False] for name in modes} for path in paths
        }
    print(f"node logs: {log_dir}")
    return finish(args.out, combined)


if __name__ == "__main__":
    sys.exit(main())
