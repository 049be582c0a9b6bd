"""``make demo``: generate a sequence, play it as a bag into the running node, print metrics.

Steps (each reuses the package's own tools):

1. ``allo-synth generate --preset demo`` writes an ALLO-like sequence (skipped if present);
2. ``allo-bag write`` turns it into a rosbag2 (MCAP) bag;
3. the ``mrad_detector`` node starts as its own process (``pose_source: topic``);
4. ``allo-bag play`` publishes the bag; this process records the node's score and mask
   for every frame and matches them to the ground truth by stamp;
5. the live metrics and latency are printed next to an offline ``allo-bag evaluate`` of
   MRAD, PAD and RXD on the same bag, and the report (with overlay images) is written.

ROS traffic stays on this machine (``config/fastdds_loopback.xml``; ``make demo`` also uses a
private network namespace where it can). ``--builtin`` runs the detectors on the built-in
synthetic example instead, without ROS.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from allo_mrad_ros import interface
from allo_mrad_ros.detector import METHODS, MradParams, profile
from allo_mrad_ros.errors import BackendError
from allo_mrad_ros.example_scene import example_pair
from allo_mrad_ros.metrics import MetricsAccumulator
from allo_mrad_ros.render import DEFAULT_SCALE
from allo_mrad_ros.resources import share_path
from allo_mrad_ros.visualise import outline

METRIC_KEYS = ("i_auroc", "p_auroc", "p_ap", "p_fpr95")


class DemoError(BackendError):
    """A step of the demo failed; the message says which and where its log is."""


def _save_rgb(path: Path, image: np.ndarray) -> None:
    cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))


def _step(number: int, text: str) -> None:
    print(f"[{number}/5] {text}", flush=True)


def _run(arguments: list[str], log: Path, what: str) -> None:
    with log.open("w") as stream:
        result = subprocess.run(arguments, stdout=stream, stderr=subprocess.STDOUT, check=False)
    if result.returncode != 0:
        raise DemoError(f"{what} failed (exit {result.returncode}); see {log}")


def _metric_row(name: str, source: str, frames: int, metrics: dict) -> str:
    cells = "".join(f"{100 * metrics[k]:>9.1f}" for k in METRIC_KEYS)
    return f"{name:<8}{source:<16}{frames:>7}{cells}"


def _prime_camera_info(node: object, intrinsics: object, node_log: Path) -> None:
    """Send camera_info until the node reports its renderer ready (GL start-up takes ~1 s),
    so the first frames of the bag are not dropped while it starts."""
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo

    from allo_mrad_ros.ros.messages import fill_camera_info

    publisher = node.create_publisher(
        CameraInfo, interface.CAMERA_INFO_TOPIC, qos_profile_sensor_data
    )
    info = fill_camera_info(CameraInfo(), intrinsics)
    deadline = time.monotonic() + 60
    while "renderer ready" not in node_log.read_text():
        if time.monotonic() > deadline:
            raise DemoError(f"the node's renderer did not start; see {node_log}")
        publisher.publish(info)
        rclpy.spin_once(node, timeout_sec=0.2)
    node.destroy_publisher(publisher)


def run_live(data: Path, out: Path, seed: int, rate: float) -> int:
    """The full demo; returns the process exit code."""
    import rclpy

    from allo_mrad_ros.ros.feed import start_node, stop_node
    from allo_mrad_ros.ros.recorder import OutputRecorder, RecordedFrame
    from allo_mrad_ros.sequence import read_sequence

    os.environ.setdefault(
        "FASTDDS_DEFAULT_PROFILES_FILE", str(share_path("config", "fastdds_loopback.xml"))
    )
    python = sys.executable
    sequence_dir, bag_dir, logs = data / "sequence", data / "bag", out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    (out / "overlays").mkdir(exist_ok=True)
    for old in (out / "overlays").glob("*.png"):
        old.unlink()

    if (sequence_dir / "frames.csv").is_file():
        _step(1, f"sequence already in {sequence_dir} (delete it to regenerate)")
    else:
        _step(1, f"generating the demo sequence into {sequence_dir} (allo-synth, seed {seed})")
        _run(
            [
                python,
                "-m",
                "allo_mrad_ros.synth.cli",
                "generate",
                "--preset",
                "demo",
                "--seed",
                str(seed),
                "--out",
                str(sequence_dir),
                "--overwrite",
                "--quiet",
            ],
            logs / "generate.log",
            "allo-synth generate",
        )
    sequence = read_sequence(sequence_dir)
    by_stamp = {frame.stamp_ns: frame for frame in sequence.frames}

    _step(2, f"writing the bag {bag_dir} (allo-bag write, MCAP)")
    _run(
        [
            python,
            "-m",
            "rosbag_tools",
            "write",
            str(sequence_dir),
            str(bag_dir),
            "--overwrite",
            "--quiet",
        ],
        logs / "write.log",
        "allo-bag write",
    )

    _step(3, "starting the mrad_detector node (pose_source: topic)")
    accumulator = MetricsAccumulator()
    latencies: list[float] = []
    saved: list[str] = []

    def on_frame(recorded: RecordedFrame) -> None:
        frame = by_stamp.get(recorded.stamp_ns)
        if frame is None:
            return
        truth = sequence.load_mask(frame)
        if truth is None:
            return
        area = int(np.count_nonzero(recorded.mask))
        accumulator.update(recorded.score, area, truth)
        if recorded.latency_ms is not None:
            latencies.append(recorded.latency_ms)
        if frame.is_anomalous and len(saved) < 8:
            image = outline(
                sequence.load_image(frame), (truth == 2).astype(np.uint8) * 255, (0, 255, 0)
            )
            path = out / "overlays" / f"{frame.name}.png"
            _save_rgb(path, outline(image, np.ascontiguousarray(recorded.mask), (255, 40, 40)))
            saved.append(path.name)

    rclpy.init()
    listener = rclpy.create_node("mrad_demo_recorder")
    recorder = OutputRecorder(listener, on_frame)
    node = start_node(logs / "node.log", "publish_overlay:=false")
    try:
        deadline = time.monotonic() + 60
        while listener.count_subscribers(interface.IMAGE_TOPIC) < 2:
            if time.monotonic() > deadline or node.poll() is not None:
                raise DemoError(f"the node did not start; see {logs / 'node.log'}")
            rclpy.spin_once(listener, timeout_sec=0.1)
        _prime_camera_info(listener, sequence.meta.camera, logs / "node.log")
        _step(4, f"playing the bag at {rate:g}x into the node and recording its outputs")
        player = subprocess.Popen(
            [
                python,
                "-m",
                "rosbag_tools",
                "play",
                str(bag_dir),
                "--rate",
                str(rate),
                "--wait-for",
                interface.IMAGE_TOPIC,
            ],
            stdout=(logs / "play.log").open("w"),
            stderr=subprocess.STDOUT,
        )
        while player.poll() is None:
            rclpy.spin_once(listener, timeout_sec=0.05)
        end = time.monotonic() + 5.0  # the last frames are still being processed
        while time.monotonic() < end:
            rclpy.spin_once(listener, timeout_sec=0.05)
        if player.returncode != 0:
            raise DemoError(f"allo-bag play failed; see {logs / 'play.log'}")
        if node.poll() is not None:
            raise DemoError(f"the node exited during the demo; see {logs / 'node.log'}")
    finally:
        stop_node(node)
        listener.destroy_node()
        rclpy.shutdown()

    _step(5, "offline evaluation of MRAD, PAD and RXD on the same bag (allo-bag evaluate)")
    offline_dir = out / "offline"
    _run(
        [
            python,
            "-m",
            "rosbag_tools",
            "evaluate",
            str(bag_dir),
            "--out",
            str(offline_dir),
            "--overwrite",
            "--quiet",
        ],
        logs / "evaluate.log",
        "allo-bag evaluate",
    )
    offline = json.loads((offline_dir / "metrics.json").read_text())

    live = accumulator.compute().as_dict()
    report = {
        "frames_in_bag": len(by_stamp),
        "frames_processed_live": recorder.frames,
        "live": {"MRAD": live},
        "latency_ms_p50": float(np.median(latencies)) if latencies else None,
        "latency_ms_p95": float(np.percentile(latencies, 95)) if latencies else None,
        "offline": offline,
        "overlays": saved,
    }
    (out / "demo.json").write_text(json.dumps(report, indent=2) + "\n")

    print()
    print(
        f"{'method':<8}{'run':<16}{'frames':>7}{'I.AUROC':>9}{'P.AUROC':>9}{'P.AP':>9}"
        f"{'P.FPR95':>9}   (percent)"
    )
    print(_metric_row("MRAD", "live (node)", recorder.frames, live))
    for name, metrics in offline["methods"].items():
        print(_metric_row(name, "offline", offline["frames"], metrics))
    if latencies:
        print(
            f"live: {recorder.frames} of {len(by_stamp)} frames processed; latency input "
            f"published -> mask received: p50 {report['latency_ms_p50']:.0f} ms, "
            f"p95 {report['latency_ms_p95']:.0f} ms"
        )
    print(
        f"report: {out}/demo.json, overlays (green: truth, red: detected) in {out}/overlays/, "
        f"offline report with curves in {offline_dir}/"
    )
    return 0


def run_builtin(out: Path, profile_name: str, reference_scale: float) -> int:
    """Run the three detectors on the built-in synthetic example (no ROS)."""
    params: MradParams = profile(profile_name)
    pair = example_pair()
    height, width = pair.query.shape[:2]
    ref_size = (round(width * reference_scale), round(height * reference_scale))
    reference = cv2.resize(pair.reference, ref_size, interpolation=cv2.INTER_AREA)
    truth = pair.object_mask > 0
    out.mkdir(parents=True, exist_ok=True)
    print(
        f"built-in example: {width}x{height} query, {ref_size[0]}x{ref_size[1]} reference, "
        f"object of {np.count_nonzero(truth)} px; profile {profile_name!r}"
    )
    print(f"{'method':<8}{'frame':<8}{'anomalous':>10}{'area px':>10}{'IoU':>7}{'ms':>8}")
    for name, method in METHODS.items():
        for label, query in (("object", pair.query), ("clean", pair.clean_query)):
            result = method(query, reference, params)
            found = result.mask > 0
            union = np.count_nonzero(found | truth)
            iou = np.count_nonzero(found & truth) / union if label == "object" else float("nan")
            print(
                f"{name:<8}{label:<8}{result.anomalous!s:>10}{result.area:>10}"
                f"{iou:>7.2f}{result.timings_ms['total']:>8.1f}"
            )
            if label == "object":
                image = outline(
                    outline(query, pair.object_mask, (0, 255, 0)), result.mask, (255, 0, 0)
                )
                _save_rgb(out / f"{name.lower()}_overlay.png", image)
    print(f"overlays (green: ground truth, red: detected) in {out}/")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=Path("data/demo"), help="sequence and bag")
    parser.add_argument("--out", type=Path, default=Path("reports/demo"), help="report folder")
    parser.add_argument("--seed", type=int, default=0, help="sequence seed")
    parser.add_argument("--rate", type=float, default=1.0, help="bag playback speed multiple")
    parser.add_argument("--builtin", action="store_true", help="built-in example, no ROS")
    parser.add_argument("--profile", default="default", help="detector profile (--builtin)")
    parser.add_argument("--reference-scale", type=float, default=DEFAULT_SCALE, help="(--builtin)")
    args = parser.parse_args(argv)
    if args.builtin:
        return run_builtin(args.out, args.profile, args.reference_scale)
    try:
        return run_live(args.data, args.out, args.seed, args.rate)
    except DemoError as error:
        print(f"demo failed: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
