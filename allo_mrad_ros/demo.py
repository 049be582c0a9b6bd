"""``make demo``: generate a sequence, play it as a bag into the running node, print metrics.

Steps (each reuses the package's own tools):

1. ``allo-synth generate --preset demo`` writes an ALLO-like sequence (skipped if present);
2. ``allo-bag write`` turns it into a rosbag2 (MCAP) bag;
3. the ``mrad_detector`` node starts as its own process (``pose_source: topic``);
4. ``allo-bag play`` publishes the bag; this process records the node's score map, mask and
   result (with the frame's image score) for every frame and matches them to the ground
   truth by stamp;
5. the live metrics and latency are printed next to an offline ``allo-bag evaluate`` of
   MRAD, PAD and RXD on the same bag, and the report (with overlay images) is written.

The latency this process measures (input published to outputs received here) is shown
beside the node's own figures from its ``/diagnostics``: the frames' age since their image
was published when the node took them and when it had published their outputs, and the
frames it dropped, so a recorder short of CPU does not pass for a slow node.

The live row is computed as the offline one is (the node's score map and image score), so
when the node processes all the frames the live and offline MRAD rows are equal.

ROS traffic stays on this machine (``config/fastdds_loopback.xml``; ``make demo`` also uses a
private network namespace where it can). ``--builtin`` runs the detectors on the built-in
synthetic example instead, without ROS.
"""

from __future__ import annotations

import json
import queue
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from allo_mrad_ros import interface
from allo_mrad_ros.detector import METHODS, MradParams, profile
from allo_mrad_ros.errors import BackendError
from allo_mrad_ros.example_scene import example_pair
from allo_mrad_ros.metrics import MetricsAccumulator
from allo_mrad_ros.render import DEFAULT_SCALE
from allo_mrad_ros.targets import OutputArgumentParser, output_path
from allo_mrad_ros.visualise import outline

METRIC_KEYS = ("i_auroc", "p_auroc", "p_ap", "p_fpr95")
# The node's own figures the report carries, from its /diagnostics pipeline status.
NODE_AGES = (
    "input_age_taken_ms_p50",
    "input_age_taken_ms_p95",
    "input_age_published_ms_p50",
    "input_age_published_ms_p95",
)
NODE_COUNTERS = (
    "frames_received",
    "frames_processed",
    "frames_dropped_stale",
    "frames_dropped_too_old",
)


class DemoError(BackendError):
    """A step of the demo failed; the message says which and where its log is."""


def _save_rgb(path: Path, image: np.ndarray) -> None:
    cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))


def _step(number: int, text: str) -> None:
    print(f"[{number}/5] {text}", flush=True)


def _module(name: str, *arguments: str) -> list[str]:
    """The command line that runs ``python -m name arguments...`` with this interpreter."""
    return [sys.executable, "-m", name, *arguments]


def _run(arguments: list[str], log: Path, what: str) -> None:
    with log.open("w") as stream:
        result = subprocess.run(arguments, stdout=stream, stderr=subprocess.STDOUT, check=False)
    if result.returncode != 0:
        raise DemoError(f"{what} failed (exit {result.returncode}); see {log}")


def _metric_row(name: str, source: str, frames: int, metrics: dict) -> str:
    cells = "".join(f"{100 * metrics[k]:>9.1f}" for k in METRIC_KEYS)
    return f"{name:<8}{source:<16}{frames:>7}{cells}"


@dataclass(frozen=True)
class DemoPaths:
    """Where the demo reads and writes: the sequence and bag under ``data``, the report under
    ``out``."""

    data: Path
    out: Path

    @property
    def sequence(self) -> Path:
        return self.data / "sequence"

    @property
    def bag(self) -> Path:
        return self.data / "bag"

    @property
    def logs(self) -> Path:
        return self.out / "logs"

    @property
    def overlays(self) -> Path:
        return self.out / "overlays"

    @property
    def offline(self) -> Path:
        return self.out / "offline"

    def prepare(self) -> None:
        """Create the report folders and remove the overlays of an earlier run."""
        self.logs.mkdir(parents=True, exist_ok=True)
        self.overlays.mkdir(exist_ok=True)
        for old in self.overlays.glob("*.png"):
            old.unlink()


class RecordedOutputs(Protocol):
    """What :class:`LiveTally` reads of a recorded frame (``ros.recorder.RecordedFrame``)."""

    stamp_ns: int
    score: np.ndarray
    mask: np.ndarray
    image_score: float
    latency_ms: float | None


class LiveTally:
    """The live row: the node's outputs of each frame against the sequence's ground truth.

    A frame enters the metrics exactly as ``allo-bag evaluate`` enters it: the node's pixel
    score map (``~/score``) and its image score (``image_score`` of ``~/result``, the frame
    score I.AUROC ranks), so when the node processes every frame the live MRAD row equals
    the offline one. The mask only draws the overlays.

    Parameters
    ----------
    sequence : Sequence
        The played sequence (ground-truth masks, images for the overlays).
    overlay_dir : Path
        Where the overlays of the first ``max_overlays`` anomalous frames are written.
    """

    def __init__(self, sequence: object, overlay_dir: Path, max_overlays: int = 8) -> None:
        self.sequence = sequence
        self.by_stamp = {frame.stamp_ns: frame for frame in sequence.frames}
        self.overlay_dir = overlay_dir
        self.max_overlays = max_overlays
        self.accumulator = MetricsAccumulator()
        self.latencies: list[float] = []
        self.overlays: list[str] = []
        self.frames = 0
        self.seen: set[int] = set()

    def add(self, recorded: RecordedOutputs) -> None:
        """Add the node's outputs for one frame (frames not in the sequence are ignored)."""
        frame = self.by_stamp.get(recorded.stamp_ns)
        if frame is None:
            return
        truth = self.sequence.load_mask(frame)
        if truth is None:
            return
        self.accumulator.update(recorded.score, recorded.image_score, truth)
        self.frames += 1
        self.seen.add(recorded.stamp_ns)
        if recorded.latency_ms is not None:
            self.latencies.append(recorded.latency_ms)
        if frame.is_anomalous and len(self.overlays) < self.max_overlays:
            self._save_overlay(frame, truth, recorded.mask)

    def _save_overlay(self, frame: object, truth: np.ndarray, mask: np.ndarray) -> None:
        image = outline(
            self.sequence.load_image(frame), (truth == 2).astype(np.uint8) * 255, (0, 255, 0)
        )
        path = self.overlay_dir / f"{frame.name}.png"
        _save_rgb(path, outline(image, np.ascontiguousarray(mask), (255, 40, 40)))
        self.overlays.append(path.name)

    def missing(self) -> list[str]:
        """Names of the sequence's frames the node produced no outputs for."""
        return [frame.name for stamp, frame in self.by_stamp.items() if stamp not in self.seen]

    def metrics(self) -> dict[str, float]:
        """The live MRAD metrics (``i_auroc``, ``p_auroc``, ``p_ap``, ``p_fpr95``, ...)."""
        return self.accumulator.compute().as_dict()

    def latency_ms(self, percentile: float) -> float | None:
        """A percentile of the input-published to outputs-received latency, if any."""
        return float(np.percentile(self.latencies, percentile)) if self.latencies else None


def generate_sequence(paths: DemoPaths, seed: int) -> None:
    """Step 1: ``allo-synth generate --preset demo``, unless the sequence is already there."""
    if (paths.sequence / "frames.csv").is_file():
        _step(1, f"sequence already in {paths.sequence} (delete it to regenerate)")
        return
    _step(1, f"generating the demo sequence into {paths.sequence} (allo-synth, seed {seed})")
    _run(
        _module(
            "allo_mrad_ros.synth.cli",
            "generate",
            "--preset",
            "demo",
            "--seed",
            str(seed),
            "--out",
            str(paths.sequence),
            "--overwrite",
            "--quiet",
        ),
        paths.logs / "generate.log",
        "allo-synth generate",
    )


def write_bag(paths: DemoPaths) -> None:
    """Step 2: ``allo-bag write`` the sequence as an MCAP bag."""
    _step(2, f"writing the bag {paths.bag} (allo-bag write, MCAP)")
    _run(
        _module(
            "rosbag_tools", "write", str(paths.sequence), str(paths.bag), "--overwrite", "--quiet"
        ),
        paths.logs / "write.log",
        "allo-bag write",
    )


def _wait_for_node(listener: object, node: subprocess.Popen, node_log: Path) -> None:
    """Wait until the node subscribes to the image topic (the recorder is the other
    subscriber)."""
    import rclpy

    deadline = time.monotonic() + 60
    while listener.count_subscribers(interface.IMAGE_TOPIC) < 2:
        if time.monotonic() > deadline or node.poll() is not None:
            raise DemoError(f"the node did not start; see {node_log}")
        rclpy.spin_once(listener, timeout_sec=0.1)


def _prime_camera_info(node: object, intrinsics: object, node_log: Path) -> None:
    """Send camera_info until the node reports its renderer and detector warmed up (~1 s),
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
    while "warmed up" not in node_log.read_text():
        if time.monotonic() > deadline:
            raise DemoError(f"the node's renderer did not start; see {node_log}")
        publisher.publish(info)
        rclpy.spin_once(node, timeout_sec=0.2)
    node.destroy_publisher(publisher)


def _play_bag(listener: object, paths: DemoPaths, rate: float) -> None:
    """``allo-bag play`` the bag while the listener records, then give the node 5 s to
    finish its last frames."""
    import rclpy

    log = paths.logs / "play.log"
    with log.open("w") as stream:
        player = subprocess.Popen(
            _module(
                "rosbag_tools",
                "play",
                str(paths.bag),
                "--rate",
                str(rate),
                # The recorder subscribes to the image too: the pose and camera_info
                # topics have only the node, so their publishers wait for it.
                "--wait-for",
                interface.IMAGE_TOPIC,
                interface.POSE_TOPIC,
                interface.CAMERA_INFO_TOPIC,
            ),
            stdout=stream,
            stderr=subprocess.STDOUT,
        )
        while player.poll() is None:
            rclpy.spin_once(listener, timeout_sec=0.05)
    end = time.monotonic() + 5.0
    while time.monotonic() < end:
        rclpy.spin_once(listener, timeout_sec=0.05)
    if player.returncode != 0:
        raise DemoError(f"allo-bag play failed; see {log}")


def run_node_on_bag(paths: DemoPaths, tally: LiveTally, rate: float) -> dict[str, str]:
    """Steps 3 and 4: start the node, play the bag into it and feed its outputs to
    ``tally``; returns the values of the node's last ``/diagnostics`` pipeline status."""
    import rclpy

    from allo_mrad_ros.ros.node_process import start_node, stop_node
    from allo_mrad_ros.ros.recorder import OutputRecorder

    _step(3, "starting the mrad_detector node (pose_source: topic)")
    node_log = paths.logs / "node.log"
    rclpy.init()
    listener = rclpy.create_node("mrad_demo_recorder")
    # The tally (PNG masks read, metrics updated, overlays written) runs beside the
    # recorder's callbacks, so that they take the node's outputs as they come.
    recorded: queue.Queue = queue.Queue()
    failures: list[Exception] = []
    tallying = threading.Thread(
        target=_tally_all, args=(recorded, tally, failures), name="demo_tally"
    )
    tallying.start()
    recorder = OutputRecorder(listener, recorded.put)
    # The live metrics rank the full-resolution map, as the offline evaluation does.
    node = start_node(node_log, "publish_overlay:=false", "score_full_resolution:=true")
    try:
        _wait_for_node(listener, node, node_log)
        _prime_camera_info(listener, tally.sequence.meta.camera, node_log)
        _step(4, f"playing the bag at {rate:g}x into the node and recording its outputs")
        _play_bag(listener, paths, rate)
        if node.poll() is not None:
            raise DemoError(f"the node exited during the demo; see {node_log}")
    finally:
        stop_node(node)
        listener.destroy_node()
        rclpy.shutdown()
        recorded.put(None)
        tallying.join()
    if failures:
        raise failures[0]
    return recorder.node_status


def _tally_all(recorded: queue.Queue, tally: LiveTally, failures: list[Exception]) -> None:
    """Add each recorded frame to ``tally`` until None arrives; a failure is kept in
    ``failures`` (the later frames are then only taken off the queue)."""
    for frame in iter(recorded.get, None):
        if not failures:
            try:
                tally.add(frame)
            except Exception as error:  # raised again in the demo's own thread
                failures.append(error)


def evaluate_offline(paths: DemoPaths) -> dict:
    """Step 5: ``allo-bag evaluate`` MRAD, PAD and RXD on the same bag; its metrics.json."""
    _step(5, "offline evaluation of MRAD, PAD and RXD on the same bag (allo-bag evaluate)")
    _run(
        _module(
            "rosbag_tools",
            "evaluate",
            str(paths.bag),
            "--out",
            str(paths.offline),
            "--overwrite",
            "--quiet",
            "--reuse-reference",
        ),
        paths.logs / "evaluate.log",
        "allo-bag evaluate",
    )
    return json.loads((paths.offline / "metrics.json").read_text())


def node_figures(status: dict[str, str]) -> dict[str, float | int | None]:
    """The node's own figures of a ``/diagnostics`` pipeline status's values: the input ages
    (:data:`NODE_AGES`, ms) and frame counters (:data:`NODE_COUNTERS`); None for one it
    did not report (no frame processed, or a counter never raised: 0)."""
    figures: dict[str, float | int | None] = {}
    for key in NODE_AGES:
        try:
            figures[key] = float(status[key])
        except (KeyError, ValueError):
            figures[key] = None
    for key in NODE_COUNTERS:
        value = status.get(key, "0" if key.startswith("frames_dropped") else "")
        figures[key] = int(value) if value.isdigit() else None
    return figures


def build_report(tally: LiveTally, offline: dict, node_status: dict[str, str]) -> dict:
    """The demo's report: the live and offline metrics, the latency this process measured,
    the node's own figures (:func:`node_figures`) and the overlay names."""
    return {
        "frames_in_bag": len(tally.by_stamp),
        "frames_processed_live": tally.frames,
        "frames_missing_live": tally.missing(),
        "live": {"MRAD": tally.metrics()},
        "latency_ms_p50": tally.latency_ms(50),
        "latency_ms_p95": tally.latency_ms(95),
        "node": node_figures(node_status),
        "offline": offline,
        "overlays": tally.overlays,
    }


def write_report(
    paths: DemoPaths, tally: LiveTally, offline: dict, node_status: dict[str, str]
) -> dict:
    """Write ``demo.json`` (:func:`build_report`) and return it."""
    report = build_report(tally, offline, node_status)
    (paths.out / "demo.json").write_text(json.dumps(report, indent=2) + "\n")
    return report


def node_line(report: dict) -> str:
    """The node's own figures in words, or why there are none."""
    node = report.get("node") or {}
    if node.get("input_age_published_ms_p50") is None:
        return "node: no input-age figures in its /diagnostics (no frame processed)"
    return (
        f"node (its /diagnostics): age since the image was published when taken p50 "
        f"{node['input_age_taken_ms_p50']:.0f} ms, p95 {node['input_age_taken_ms_p95']:.0f} "
        f"ms; when its outputs were published p50 {node['input_age_published_ms_p50']:.0f} "
        f"ms, p95 {node['input_age_published_ms_p95']:.0f} ms; {node['frames_processed']} of "
        f"{node['frames_received']} images received processed, "
        f"{node['frames_dropped_too_old']} dropped as older than max_input_age_s, "
        f"{node['frames_dropped_stale']} replaced by a newer one before being taken"
    )


def missing_reason(report: dict) -> str:
    """Why the live row lacks frames, from the node's own count: the node's drops (it keeps
    the newest image), or this recorder's missing outputs the node did publish."""
    processed = (report.get("node") or {}).get("frames_processed")
    live = report["frames_processed_live"]
    if processed is not None and processed > live:
        return (
            f"the node processed {processed} frames: this recorder, short of CPU itself, "
            f"missed the outputs of {processed - live}"
        )
    return "the node keeps the newest image and drops the ones it cannot keep up with"


def print_summary(paths: DemoPaths, report: dict) -> None:
    """The table of both rows, the live frame count and latency, and where the report is."""
    offline = report["offline"]
    print()
    print(
        f"{'method':<8}{'run':<16}{'frames':>7}{'I.AUROC':>9}{'P.AUROC':>9}{'P.AP':>9}"
        f"{'P.FPR95':>9}   (percent)"
    )
    live_frames = report["frames_processed_live"]
    print(_metric_row("MRAD", "live (node)", live_frames, report["live"]["MRAD"]))
    for name, metrics in offline["methods"].items():
        print(_metric_row(name, "offline", offline["frames"], metrics))
    line = f"live: {live_frames} of {report['frames_in_bag']} frames processed"
    if report["latency_ms_p50"] is not None:
        line += (
            f"; latency input published -> outputs received: p50 "
            f"{report['latency_ms_p50']:.0f} ms, p95 {report['latency_ms_p95']:.0f} ms"
        )
    print(line)
    print(node_line(report))
    if live_frames < report["frames_in_bag"]:
        missing = report["frames_missing_live"]
        shown = ", ".join(missing[:5]) + (", ..." if len(missing) > 5 else "")
        print(f"no outputs for {shown}: the live row covers fewer frames than the offline rows")
        print(f"  {missing_reason(report)}")
    print(
        f"report: {paths.out}/demo.json, overlays (green: truth, red: detected) in "
        f"{paths.overlays}/, offline report with curves in {paths.offline}/"
    )


def run_live(data: Path, out: Path, seed: int, rate: float) -> int:
    """The full demo (steps 1-5 of the module's docstring); returns the exit status."""
    from allo_mrad_ros.ros.node_process import use_loopback_profile
    from allo_mrad_ros.sequence import read_sequence

    use_loopback_profile()
    paths = DemoPaths(data, out)
    paths.prepare()
    generate_sequence(paths, seed)
    write_bag(paths)
    tally = LiveTally(read_sequence(paths.sequence), paths.overlays)
    node_status = run_node_on_bag(paths, tally, rate)
    offline = evaluate_offline(paths)
    print_summary(paths, write_report(paths, tally, offline, node_status))
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
    parser = OutputArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=Path("data/demo"), help="sequence and bag")
    parser.add_argument(
        "--out", type=output_path, default=Path("reports/demo"), help="report folder"
    )
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
