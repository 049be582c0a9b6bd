"""Where one frame of the node's path spends its time (``make profile-node``).

Runs what the node's processing does for a frame, in this process and without DDS peers:
decode the ``sensor_msgs/Image`` (rgb8, 1920x1080), render the reference, detect, and build
and publish the default outputs (``~/mask``, ``~/score``, ``~/overlay``, ``~/anomaly``) on
real rclpy publishers that report one subscriber each, so messages are built and serialised
as in the node. cProfile over ``--frames`` frames after one warm-up frame; prints the stages'
share and the functions with the most own time.

Usage: ``python -m benchmarks.node_profile --frames 20``
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import sys
import time
from pathlib import Path

import numpy as np
import rclpy
from sensor_msgs.msg import Image

from allo_mrad_ros import interface
from allo_mrad_ros.camera import ALLO_INTRINSICS
from allo_mrad_ros.pipeline import Pipeline, PipelineConfig
from allo_mrad_ros.render import ReferenceProvider
from allo_mrad_ros.ros import messages
from allo_mrad_ros.ros.outputs import Outputs
from allo_mrad_ros.ros.parameters import default_config
from allo_mrad_ros.view import View
from benchmarks import add_names_option, finish, machine_facts
from benchmarks.node_session import SUN, still_frames

# The node's default output settings: the overlay published, the reference not.
CONFIG = default_config()


class _Listened:
    """A publisher that reports one subscriber, so the output is built and published."""

    def __init__(self, publisher: object) -> None:
        self._publisher = publisher

    def get_subscription_count(self) -> int:
        return 1

    def publish(self, msg: object) -> None:
        self._publisher.publish(msg)


# The publishers of :class:`Outputs` that a profile can report as subscribed.
OUTPUT_NAMES = (
    "mask",
    "mask_info",
    "score",
    "score_info",
    "anomaly",
    "result",
    "regions",
    "reference",
    "reference_info",
    "overlay",
    "overlay_info",
)


def _outputs(node: object, subscribed: tuple[str, ...]) -> Outputs:
    outputs = Outputs(node)
    for name in subscribed:
        setattr(outputs, name, _Listened(getattr(outputs, name)))
    return outputs


def profile_frames(frames: int, subscribed: tuple[str, ...]) -> tuple[pstats.Stats, dict]:
    """Profile ``frames`` frames of decode, render, detect and publish; stats and stage ms."""
    pose, images = still_frames()
    msgs = [messages.fill_image(Image(), None, rgb, interface.RGB8) for rgb in images]
    rclpy.init()
    node = rclpy.create_node("mrad_profile")
    try:
        outputs = _outputs(node, subscribed)
        provider = ReferenceProvider(None, ALLO_INTRINSICS, PipelineConfig().render)
        pipeline = Pipeline(provider)
        view = View(pose, np.asarray(SUN, dtype=np.float64) / np.linalg.norm(SUN))
        size = (ALLO_INTRINSICS.width, ALLO_INTRINSICS.height)
        score_map = "score" in subscribed  # as the node: the ranking map only for a reader
        stage_ms: dict[str, list[float]] = {"decode": [], "render": [], "detect": [], "publish": []}

        def one(msg: Image, record: bool) -> None:
            t0 = time.perf_counter()
            image = messages.image_to_rgb(msg, size)
            t1 = time.perf_counter()
            reference = provider.render(view)
            t2 = time.perf_counter()
            results = pipeline.detect(image, reference, score_map=score_map).results
            t3 = time.perf_counter()
            frame = type("Frame", (), {})()
            frame.primary, frame.reference = next(iter(results.values())), reference
            outputs.publish(msg.header, image, frame, config=CONFIG, score_map=score_map)
            t4 = time.perf_counter()
            if record:
                for name, (a, b) in zip(
                    stage_ms, ((t0, t1), (t1, t2), (t2, t3), (t3, t4)), strict=True
                ):
                    stage_ms[name].append(1e3 * (b - a))

        one(msgs[1], False)
        profiler = cProfile.Profile()
        profiler.enable()
        for index in range(frames):
            one(msgs[index % 2], True)
        profiler.disable()
        provider.close()
    finally:
        node.destroy_node()
        rclpy.shutdown()
    medians = {name: float(np.median(values)) for name, values in stage_ms.items()}
    return pstats.Stats(profiler), medians


def top_functions(stats: pstats.Stats, frames: int, count: int) -> list[dict]:
    """The ``count`` functions with the most own time, in ms per frame."""
    rows = []
    for (filename, line, name), (_, calls, own, cumulative, _) in stats.stats.items():
        where = f"{Path(filename).name}:{line}({name})" if line else name
        rows.append(
            {
                "function": where,
                "calls_per_frame": calls / frames,
                "own_ms_per_frame": 1e3 * own / frames,
                "cumulative_ms_per_frame": 1e3 * cumulative / frames,
            }
        )
    rows.sort(key=lambda row: row["own_ms_per_frame"], reverse=True)
    return rows[:count]


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=20, help="profiled frames")
    parser.add_argument("--top", type=int, default=15, help="functions listed")
    add_names_option(
        parser,
        "--outputs",
        OUTPUT_NAMES,
        what="output",
        help="the outputs reported as subscribed",
        default=("mask", "score", "overlay", "anomaly"),
    )
    parser.add_argument("--out", type=Path, default=Path("reports/profile_node.json"))
    args = parser.parse_args(argv)
    subscribed = tuple(args.outputs)
    stats, medians = profile_frames(args.frames, subscribed)
    rows = top_functions(stats, args.frames, args.top)
    load = os.getloadavg()
    print(
        f"one 1920x1080 frame of the node path, {args.frames} frames under cProfile, "
        f"outputs {', '.join(subscribed)}; load average {load[0]:.2f} {load[1]:.2f}"
    )
    print("stage medians (profiled, ms): " + ", ".join(f"{k} {v:.1f}" for k, v in medians.items()))
    print(f"{'own ms':>8} {'cum ms':>8} {'calls':>6}  function")
    for row in rows:
        print(
            f"{row['own_ms_per_frame']:8.2f} {row['cumulative_ms_per_frame']:8.2f} "
            f"{row['calls_per_frame']:6.0f}  {row['function']}"
        )
    report = {
        "frames": args.frames,
        "outputs": list(subscribed),
        "stage_ms_median": medians,
        "top_functions": rows,
        "load_average": list(load),
        **machine_facts(),
    }
    return finish(args.out, report)


if __name__ == "__main__":
    sys.exit(main())
