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

Where the time goes: after each run the node's own figures from ``/diagnostics`` (over its
last 1,000 processed frames): each stage of a frame's path from the image's publication to
the end of its outputs' (middleware, slot, prepare, render, hand-over, detect, publish,
:data:`allo_mrad_ros.ros.worker.STAGES`) and the frame's age when taken and when published,
p50 and p95, and the frames it dropped. ``--load N`` runs N busy loops beside the node
(:mod:`.load`: separate processes, one per core in turn, at the node's priority) and raises
the priority of this process, the feed and the recorder of the masks, where permitted, so
that a late feed or recorder is not what is measured; ``--seconds S`` publishes for S
seconds instead of until ``--frames`` masks arrived, and the latency is reported per
30-second window as well, to show whether it grows.

Usage: ``python -m benchmarks.node --frames 1000 --out reports/bench_node.json``;
``python -m benchmarks.node --load 2 --modes 1080p30 --trajectory moving --seconds 120``;
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
from visualization_msgs.msg import MarkerArray

from allo_mrad_ros.camera import ALLO_INTRINSICS, CameraIntrinsics
from allo_mrad_ros.example_scene import paste_object
from allo_mrad_ros.render import ReferenceRenderer
from allo_mrad_ros.ros.worker import STAGES
from benchmarks import add_names_option, finish, thread_cpu
from benchmarks.load import busy_loops, prioritised, renice
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
# Seconds of image stamps per window of the latency over time (--seconds runs).
WINDOW_S = 30.0
# The node's counters read before and after a run.
COUNTERS = (
    "frames_processed",
    "frames_received",
    "references_rendered",
    "references_reused",
    "frames_dropped_stale",
    "frames_dropped_too_old",
    "errors_camera_info",
    "pose_lookup_failures",
)


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


def _counters(values: dict[str, str]) -> dict[str, int]:
    """The node's cumulative counters of a ``/diagnostics`` pipeline status's values."""
    return {key: int(values[key]) for key in COUNTERS if key in values and values[key].isdigit()}


def _fresh_values(feed: CameraFeed, seconds: float = 2.5) -> dict[str, str]:
    """The values of a ``/diagnostics`` pipeline status published after this call (the node
    publishes one a second), so they include every frame it processed before."""
    feed.diagnostics.clear()
    feed.wait_for(lambda: len(feed.diagnostics) >= 2, seconds)
    return feed.diagnostic_values()


def node_stages(values: dict[str, str]) -> dict[str, dict[str, float]]:
    """The node's per-stage latency and input ages, ``{name: {"p50": ms, "p95": ms}}``, from
    a ``/diagnostics`` pipeline status's values: each of :data:`STAGES` (``latency_<stage>``),
    ``middleware_queue`` (the part of ``middleware`` in the subscription's queue), ``objects``
    (the object tracker, a part of ``publish``, where it ran), then
    ``age_taken`` and ``age_published`` (``input_age_<when>``); those it does not report are
    left out."""
    keys = {stage: f"latency_{stage}" for stage in STAGES}
    keys.update(
        middleware_queue="latency_middleware_queue",
        objects="latency_objects",
        age_taken="input_age_taken",
        age_published="input_age_published",
    )
    figures = {}
    for name, key in keys.items():
        try:
            figures[name] = {q: float(values[f"{key}_ms_{q}"]) for q in ("p50", "p95")}
        except (KeyError, ValueError):
            continue
    return figures


def latency_windows(
    arrivals: dict[int, float], window_s: float = WINDOW_S
) -> list[dict[str, float]]:
    """Latency (image stamp to mask received, ms) per ``window_s`` of image stamps from the
    first: ``start_s``, ``frames``, ``p50``, ``p95`` of each window with a mask."""
    if not arrivals:
        return []
    first = min(arrivals)
    windows: dict[int, list[float]] = {}
    for stamp, arrived in arrivals.items():
        index = int((stamp - first) / 1e9 // window_s)
        windows.setdefault(index, []).append(1e3 * (arrived - stamp / 1e9))
    return [
        {
            "start_s": index * window_s,
            "frames": len(latencies),
            "p50": float(np.median(latencies)),
            "p95": float(np.percentile(latencies, 95)),
        }
        for index, latencies in sorted(windows.items())
    ]


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
    load: int = 0,
    seconds: float | None = None,
    node_nice: int | None = None,
    objects: bool = False,
) -> dict:
    """Drive the node at ``rate_hz`` until ``frames`` masks arrived (or for ``seconds``);
    the report dictionary.

    ``node_parameters`` are extra ``name:=value`` parameters of the node; ``trajectory``
    one of :data:`~.trajectory.TRAJECTORIES` (``plan``: its frames, rendered already);
    ``load``: busy loops beside the node (:mod:`.load`), with this process raised above them;
    ``node_nice``: the node's threads reniced (None: left at the default priority, 0);
    ``objects``: also subscribe to ``~/objects/markers`` (the node then tracks objects, and
    renders the reference's depth for it, on every frame).
    """
    plan = plan or plan_feed(trajectory, rate_hz, camera)
    node_args = (f"pipelined:={str(pipelined).lower()}", *node_parameters)
    load_before = list(os.getloadavg())
    with (
        busy_loops(load),
        node_session(log_path, {}, *node_args, camera=camera) as (feed, node),
        prioritised(load > 0) as priority,
    ):
        if node_nice is not None:
            priority += "; " + renice(node.pid, node_nice)
        if objects:
            feed.node.create_subscription(
                MarkerArray, f"{feed.output_prefix}/objects/markers", lambda _msg: None, 10
            )
        warm = time.time_ns()
        while not feed.arrival["mask"] and time.time_ns() - warm < 60e9:
            feed.publish_frame(time.time_ns(), plan.images[0], plan.poses[0], SUN)
            feed.spin(0.5)
        counters_before = _counters(_fresh_values(feed))
        feed.arrival["mask"].clear()
        published: list[int] = []
        rss_mb: dict[int, float] = {}
        period = 1.0 / rate_hz
        cpu_before, threads_before = node.cpu_times(), thread_cpu.sample(node.pid)
        start = time.monotonic()
        next_time = start
        limit_s = timeout_s if seconds is None else seconds
        goal = frames if seconds is None else float("inf")
        rss_marks = (100, frames) if seconds is None else (100,)
        while len(feed.arrival["mask"]) < goal and time.monotonic() - start < limit_s:
            if time.monotonic() >= next_time:
                stamp = time.time_ns()
                index = plan.frame(len(published))
                feed.publish_frame(stamp, plan.images[index], plan.poses[index], SUN)
                published.append(stamp)
                next_time += period
            rclpy.spin_once(feed.node, timeout_sec=0.002)
            done = len(feed.arrival["mask"])
            for mark in rss_marks:
                if done >= mark and mark not in rss_mb:
                    rss_mb[mark] = node.memory_info().rss / 2**20
        cpu_after, threads_after = node.cpu_times(), thread_cpu.sample(node.pid)
        if seconds is not None:
            frames = len(feed.arrival["mask"])
            rss_mb[frames] = node.memory_info().rss / 2**20
        node_nice = node.nice()
        feed.spin(1.0)
        values_after = _fresh_values(feed)
        counters_after = _counters(values_after)
    arrivals = feed.arrival["mask"]
    stamps = sorted(arrivals)
    latencies = np.array([1e3 * (arrivals[s] - s / 1e9) for s in stamps])
    times = sorted(arrivals.values())
    fps = (len(times) - 1) / (times[-1] - times[0]) if len(times) > 1 else 0.0
    cpu_s = (cpu_after.user - cpu_before.user) + (cpu_after.system - cpu_before.system)
    before, after = rss_mb.get(100), rss_mb.get(frames)
    reused = [c.get("references_reused") for c in (counters_before, counters_after)]
    frame_ms = 1e3 / rate_hz
    return {
        "load": load,
        "objects_subscribed": objects,
        "priority": priority,
        "node_nice": node_nice,
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
        "latency_frames_p50": float(np.median(latencies)) / frame_ms,
        "latency_frames_p95": float(np.percentile(latencies, 95)) / frame_ms,
        "latency_windows": latency_windows(arrivals),
        "node_stages_ms": node_stages(values_after),
        "node_counters_delta": {
            key: counters_after[key] - counters_before.get(key, 0) for key in counters_after
        },
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


def stages_summary(report: dict) -> str:
    """The node's own figures of a run, two lines: each stage's p50/p95 in ms and the
    input ages (in frame periods too), then the frames it received, processed and
    dropped; the latency per window when there are several."""
    stages = report.get("node_stages_ms") or {}
    frame_ms = 1e3 / report["input_rate_hz"]
    cells = [
        f"{name} {f['p50']:.1f}/{f['p95']:.1f}"
        for name, f in stages.items()
        if not name.startswith("age_")
    ]
    ages = [
        f"{name[4:]} {f['p50']:.0f}/{f['p95']:.0f} ms "
        f"({f['p50'] / frame_ms:.1f}/{f['p95'] / frame_ms:.1f} frames)"
        for name, f in stages.items()
        if name.startswith("age_")
    ]
    delta = report.get("node_counters_delta", {})
    lines = [
        "  node stages p50/p95 ms: " + (", ".join(cells) or "n/a (not reported)"),
        "  node input age p50/p95: "
        + (", ".join(ages) or "n/a")
        + f"; received {delta.get('frames_received', 'n/a')}, processed "
        f"{delta.get('frames_processed', 'n/a')}, dropped: stale "
        f"{delta.get('frames_dropped_stale', 0)}, too old {delta.get('frames_dropped_too_old', 0)}"
        f"; skipped: no camera_info {delta.get('errors_camera_info', 0)}, no pose "
        f"{delta.get('pose_lookup_failures', 0)}",
        f"  feed: mask latency p50/p95 {report['latency_frames_p50']:.1f}/"
        f"{report['latency_frames_p95']:.1f} frame periods; load {report.get('load', 0)} busy "
        f"loops, {report.get('priority', '')}; node nice {report.get('node_nice', 'n/a')}",
    ]
    windows = report.get("latency_windows") or []
    if len(windows) > 1:
        lines.append(
            "  mask latency per window p50/p95 ms: "
            + ", ".join(
                f"{w['start_s']:.0f}s {w['p50']:.0f}/{w['p95']:.0f} ({w['frames']})"
                for w in windows
            )
        )
    return "\n".join(lines)


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
    parser.add_argument(
        "--load",
        type=int,
        default=0,
        help="busy loops beside the node (separate processes, one per core in turn); this "
        "process (feed and recorder) is raised above them where permitted",
    )
    parser.add_argument(
        "--seconds",
        type=float,
        default=None,
        help="publish for this many seconds per run instead of until --frames masks arrived; "
        f"the latency is also reported per {WINDOW_S:.0f} s window",
    )
    parser.add_argument(
        "--node-nice",
        type=int,
        default=None,
        help="renice the node's threads to this value (as a robot's deployment may give it "
        "priority over other jobs); default: the node stays at the default priority",
    )
    parser.add_argument(
        "--objects",
        action="store_true",
        help="also subscribe to ~/objects/markers: the node tracks objects on every frame",
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
    if args.load < 0 or (args.seconds is not None and args.seconds <= 0):
        parser.error("--load must be >= 0 and --seconds > 0")
    variants = [False, True] if args.compare_serial else [not args.serial]
    results: dict[tuple[str, str, bool], dict] = {}
    print(
        f"mrad_detector, {' '.join(args.node_param) or 'default parameters'}; outputs mask, "
        f"score, overlay{', objects/markers' if args.objects else ''}; "
        f"{f'{args.seconds:g} s' if args.seconds else f'{args.frames} frames'} per run, "
        f"{os.cpu_count()} CPUs, {args.load} busy loops; rend/f: "
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
                    args.frames,
                    rate,
                    log,
                    args.timeout,
                    camera,
                    pipelined,
                    parameters,
                    plan=plan,
                    load=args.load,
                    seconds=args.seconds,
                    node_nice=args.node_nice,
                    objects=args.objects,
                )
                results[name, trajectory, pipelined] = report
                print(summary_line(name, report), flush=True)
                print(stages_summary(report), flush=True)
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
