"""Full-HD frames into Python processes under each DDS setting (``make bench-transport``).

Three processes per run, all started with the setting's environment: a publisher (a camera
feed: images with wall-clock stamps, camera_info, pose and Sun at the mode's rate), the node
(``mrad_detector``, started as ``make demo`` and the node benchmarks start it) and a plain
rclpy subscriber of the image topic. The settings (:data:`SETTINGS`):

- ``defaults``: Fast DDS as it comes, no profile file and no environment of ours;
- ``LARGE_DATA``: ``FASTDDS_BUILTIN_TRANSPORTS=LARGE_DATA`` (Fast DDS's own switch);
- ``shm_profile``: ``config/fastdds_large_images.xml``, the deployment profile (a shared-memory
  segment that holds several full-HD frames, UDP on every interface as by default);
- ``shm_profile_reliable``: the same profile, the image published and subscribed reliable
  (the node's ``qos_overrides.<image topic>.subscription.reliability:=reliable``), as where a
  camera driver publishes reliable and the best-effort loss of large samples must be repaired;
- ``compressed``: JPEG ``CompressedImage`` on ``<image>/compressed`` (the node's
  ``image_transport:=compressed``) under the defaults; the publisher encodes every frame
  (quality 95, image_transport's default), so its CPU includes the encoding.

For each camera mode (1920x1080 at 30 Hz, 1280x720 at 60 Hz) and setting, after a warm-up
(every reader subscribed, the node has processed a frame) the publisher publishes for
``--duration`` seconds. Per receiver it reports the frames delivered (of those published in
the window), the latency from image stamp to arrival (the subscriber's callback; for the node
the ``~/result`` of the frame, which includes detection) and the CPU of the publisher and of
the receiver over the window (% of one core, from ``/proc``). The node's count is its
``frames_received`` counter of ``/diagnostics``, read while no frame is in flight before and
after the window. Images are the still pose's render with sensor-like noise (normal, sigma 2),
so JPEG sizes are those of a camera's, not of a clean render's.

The defaults and ``LARGE_DATA`` do not confine traffic to this machine: run the bench in a
private network namespace (``make bench-transport`` does); it refuses to run where any other
interface than loopback exists unless ``--allow-network``.

Usage: ``python -m benchmarks.transport --duration 30 --out reports/bench_transport.json``;
``--settings``, ``--modes`` pick a part, ``--profile FILE`` adds a Fast DDS profile of one's own
(a segment size, say) as setting ``profile:<file stem>``, ``--no-node`` leaves the node out.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from benchmarks import add_names_option, finish, machine_facts
from harness.dds import process_domain

if TYPE_CHECKING:  # the ROS side is imported by the processes that need it, not by the tests
    from harness.feed import CameraFeed

REPO = Path(__file__).resolve().parents[1]
# Camera modes: name -> (width, height, frame rate in Hz); as benchmarks.node measures.
MODES = {"1080p30": (1920, 1080, 30.0), "720p60": (1280, 720, 60.0)}
# Environment variables of ROS and Fast DDS that choose transports or confine discovery:
# every setting starts from none of them, so the Makefile's test settings do not leak in.
DDS_VARIABLES = (
    "FASTDDS_DEFAULT_PROFILES_FILE",
    "FASTRTPS_DEFAULT_PROFILES_FILE",
    "FASTDDS_BUILTIN_TRANSPORTS",
    "ROS_AUTOMATIC_DISCOVERY_RANGE",
    "ROS_STATIC_PEERS",
    "ROS_LOCALHOST_ONLY",
)
DEPLOYMENT_PROFILE = Path("config") / "fastdds_large_images.xml"
# Sensor-like noise on the published images (standard deviation, grey levels).
NOISE_SIGMA = 2.0
# The node's /diagnostics period while measured: the counter is read twice per run.
DIAGNOSTICS_PERIOD_S = 0.5
# Quiet time around the window: frames in flight arrive, and (with the node) a fresh counter
# is published after them.
QUIET_S = 1.5
QUIET_WITHOUT_NODE_S = 0.5
REQUIRED_KEYS = (
    "setting",
    "mode",
    "receiver",
    "delivered_ratio",
    "latency_ms_p50",
    "latency_ms_p95",
    "cpu_publisher_percent",
    "cpu_receiver_percent",
    "deployment",
)


def profile_variables(path: Path) -> dict[str, str]:
    """The environment that makes Fast DDS read profile file ``path``: Fast DDS 3 (Kilted)
    reads ``FASTDDS_DEFAULT_PROFILES_FILE``, Fast DDS 2 (Humble's 2.6, Jazzy's 2.14) only
    ``FASTRTPS_DEFAULT_PROFILES_FILE``."""
    return {"FASTDDS_DEFAULT_PROFILES_FILE": str(path), "FASTRTPS_DEFAULT_PROFILES_FILE": str(path)}


class TransportBenchError(RuntimeError):
    """A run of the transport bench could not be measured (a process failed or hung)."""


@dataclass(frozen=True)
class Setting:
    """One way of carrying the images: environment variables and the image transport."""

    name: str
    description: str
    environment: Mapping[str, str]
    compressed: bool = False
    reliable: bool = False


SETTINGS: dict[str, Setting] = {
    setting.name: setting
    for setting in (
        Setting("defaults", "Fast DDS defaults (no profile file)", {}),
        Setting(
            "LARGE_DATA",
            "FASTDDS_BUILTIN_TRANSPORTS=LARGE_DATA",
            {"FASTDDS_BUILTIN_TRANSPORTS": "LARGE_DATA"},
        ),
        Setting(
            "shm_profile",
            f"FASTDDS_DEFAULT_PROFILES_FILE={DEPLOYMENT_PROFILE.as_posix()}",
            profile_variables(REPO / DEPLOYMENT_PROFILE),
        ),
        Setting(
            "shm_profile_reliable",
            "the same profile, image publisher and subscriptions reliable",
            profile_variables(REPO / DEPLOYMENT_PROFILE),
            reliable=True,
        ),
        Setting(
            "compressed",
            "CompressedImage (JPEG, quality 95) under the defaults",
            {},
            compressed=True,
        ),
    )
}
# The setting docs/distro.md recommends for robots.
DEPLOYMENT_SETTING = "shm_profile"


# --- pure parts ---------------------------------------------------------------------------


def setting_environment(base: Mapping[str, str], setting: Setting, domain_id: int) -> dict:
    """The environment of a run's processes: ``base`` without any DDS choice of its own
    (:data:`DDS_VARIABLES`), plus the setting's variables, Fast DDS and ``domain_id``."""
    environment = {k: v for k, v in base.items() if k not in DDS_VARIABLES}
    environment.update(setting.environment)
    environment["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
    environment["ROS_DOMAIN_ID"] = str(domain_id)
    return environment


def delivered_ratio(published: Sequence[int], received: Sequence[int]) -> float:
    """The fraction of ``published`` stamps that are among ``received`` (duplicates and
    stamps from outside the window do not count). Raises ValueError when nothing was
    published."""
    if not published:
        raise ValueError("no frame was published in the window: no delivered ratio")
    window = set(published)
    return len(window.intersection(received)) / len(window)


def latencies_ms(published: Sequence[int], arrivals: Mapping[int, float]) -> list[float]:
    """Milliseconds from each published stamp (ns, wall clock) to its arrival (s, wall
    clock), for the published frames that arrived, in publishing order."""
    return [1e3 * (arrivals[stamp] - stamp / 1e9) for stamp in published if stamp in arrivals]


def percentiles(values: Sequence[float], quantiles: Sequence[float] = (50, 95)) -> list:
    """The ``quantiles`` (percent) of ``values``, linearly interpolated; None for each when
    there are no values."""
    if not values:
        return [None for _ in quantiles]
    return [float(np.percentile(np.asarray(values, float), q)) for q in quantiles]


def cpu_seconds(stat: str, ticks_per_s: int) -> float:
    """User + system CPU seconds of a process from the text of its ``/proc/<pid>/stat``."""
    # Fields after the command, which may itself hold spaces and parentheses.
    fields = stat[stat.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / ticks_per_s


def process_cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` now, read from ``/proc``."""
    return cpu_seconds(Path(f"/proc/{pid}/stat").read_text(), os.sysconf("SC_CLK_TCK"))


def cpu_percent(before: float, after: float, wall_s: float) -> float:
    """CPU use between two samples as percent of one core."""
    return 100.0 * (after - before) / wall_s


def make_row(
    *,
    setting: str,
    mode: str,
    receiver: str,
    published: Sequence[int],
    received: Sequence[int],
    arrivals: Mapping[int, float],
    cpu_publisher_percent: float,
    cpu_receiver_percent: float,
    **extra: object,
) -> dict:
    """One row of the report: a receiver's delivered ratio, latency and both sides' CPU.

    ``received`` are the stamps counted as delivered; ``arrivals`` the arrival times the
    latency is measured on (for the node, of its ``~/result``: a subset). ``extra`` keys
    (load average, message size, ...) are kept.
    """
    p50, p95 = percentiles(latencies_ms(published, arrivals))
    return {
        "setting": setting,
        "mode": mode,
        "receiver": receiver,
        "frames_published": len(published),
        "frames_delivered": len(set(published).intersection(received)),
        "delivered_ratio": delivered_ratio(published, received),
        "latency_ms_p50": p50,
        "latency_ms_p95": p95,
        "cpu_publisher_percent": cpu_publisher_percent,
        "cpu_receiver_percent": cpu_receiver_percent,
        "deployment": setting == DEPLOYMENT_SETTING,
        **extra,
    }


def table(rows: Sequence[dict]) -> str:
    """The delivery table as printed: one line per setting, mode and receiver."""

    def ms(value: float | None) -> str:
        return "n/a" if value is None else f"{value:.1f}"

    lines = [
        f"{'setting':<20} {'mode':<8} {'receiver':<10} {'delivered':>15} {'p50 ms':>8} "
        f"{'p95 ms':>8} {'CPU pub %':>9} {'CPU recv %':>10} {'load':>5}"
    ]
    for row in rows:
        delivered = (
            f"{row['frames_delivered']}/{row['frames_published']} "
            f"{100 * row['delivered_ratio']:.1f}%"
        )
        mark = " *" if row["deployment"] else ""
        lines.append(
            f"{row['setting']:<20} {row['mode']:<8} {row['receiver']:<10} {delivered:>15} "
            f"{ms(row['latency_ms_p50']):>8} {ms(row['latency_ms_p95']):>8} "
            f"{row['cpu_publisher_percent']:>9.0f} {row['cpu_receiver_percent']:>10.0f} "
            f"{row.get('load_average', [float('nan')])[0]:>5.2f}{mark}"
        )
    return "\n".join(lines)


def interfaces(net_dev: str) -> list[str]:
    """Network interfaces besides loopback in the text of ``/proc/net/dev`` (none inside a
    private network namespace)."""
    names = (line.split(":", 1)[0].strip() for line in net_dev.splitlines() if ":" in line)
    return sorted(name for name in names if name != "lo")


def other_interfaces() -> list[str]:
    """Network interfaces besides loopback in this process's network namespace
    (``/proc/self/net/dev``; ``/sys/class/net`` shows the namespace sysfs was mounted in)."""
    try:
        return interfaces(Path("/proc/self/net/dev").read_text())
    except OSError:
        return []


# --- the processes ------------------------------------------------------------------------


def publish(args: argparse.Namespace) -> int:
    """The publisher process: warm up, then publish ``--duration`` seconds at the mode's rate.

    Prints ``window start`` and ``window end`` (flushed) for the orchestrator to sample CPU,
    and writes the published stamps, the node's ``~/result`` arrivals and its
    ``frames_received`` before and after the window to ``--out``.
    """
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import Image

    from allo_mrad_ros import interface
    from allo_mrad_ros.ros.messages import fill_image, stamp_to_ns
    from benchmarks.node import camera_of
    from benchmarks.node_session import SUN
    from harness.feed import CameraFeed, compress_image

    width, height, rate_hz = MODES[args.mode]
    stored = np.load(args.frames)
    pose, images = stored["pose"], [stored["clean"], stored["with_object"]]
    rclpy.init()
    feed = CameraFeed(
        camera_of(width, height),
        keep_messages=False,
        compression="jpeg" if args.compressed else "",
        outputs=(),
    )
    if args.reliable:  # a driver's reliable publisher in place of the feed's best-effort one
        topic = feed.pub_image.topic_name
        feed.node.destroy_publisher(feed.pub_image)
        feed.pub_image = feed.node.create_publisher(Image, topic, _reliable_qos())
    if args.node:
        feed.subscribe("result", DiagnosticArray)
    messages = []
    for rgb in images:
        if args.compressed:
            msg = compress_image(rgb, "jpeg")
        else:
            msg = fill_image(Image(), feed.camera_info().header, rgb, interface.RGB8)
        msg.header.frame_id = feed.frame_id
        messages.append(msg)
    sizes = [len(msg.data) for msg in messages]

    def counter_after(wall_s: float, timeout_s: float = 10.0) -> int | None:
        """The node's frames_received in the first /diagnostics stamped after ``wall_s``."""
        found: list[int] = []

        def fresh() -> bool:
            for msg in reversed(feed.diagnostics):
                if stamp_to_ns(msg.header.stamp) / 1e9 >= wall_s:
                    values = {kv.key: kv.value for kv in msg.status[0].values}
                    found.append(int(values["frames_received"]))
                    return True
            return False

        feed.wait_for(fresh, timeout_s)
        return found[0] if found else None

    def play(seconds: float, stamps: list[int]) -> None:
        start = time.monotonic()
        next_frame = start
        while time.monotonic() - start < seconds:
            now = time.monotonic()
            if now >= next_frame:
                stamp, index = time.time_ns(), len(stamps) % 2
                if args.compressed:  # encoded per frame, as a driver's compressed publisher does
                    feed.publish_frame(stamp, images[index], pose, SUN)
                else:  # the message is built once: a driver fills its buffer, no Python copy
                    feed.publish_frame(stamp, None, pose, SUN, image=messages[index])
                stamps.append(stamp)
                next_frame += 1.0 / rate_hz
                if next_frame < now - 1.0:  # a stall of this process: do not burst after it
                    next_frame = now
            rclpy.spin_once(feed.node, timeout_sec=max(0.0, min(0.002, next_frame - now)))

    readers = 2 if args.node else 1
    report: dict = {"message_bytes": sizes}
    try:
        subscribed = feed.wait_for(
            lambda: feed.pub_image.get_subscription_count() >= readers, 120.0
        )
        if not subscribed:
            raise TransportBenchError(
                f"{feed.pub_image.get_subscription_count()} of {readers} readers subscribed "
                f"to {feed.pub_image.topic_name} within 120 s"
            )
        warm_up: list[int] = []
        warm_start = time.monotonic()
        # Every reader has met frames, and the node has rendered and processed one.
        while time.monotonic() - warm_start < 60.0:
            play(1.0, warm_up)
            if not args.node or feed.arrival["result"]:
                break
        report["node_processed_in_warm_up"] = bool(feed.arrival["result"])
        quiet_s = QUIET_S if args.node else QUIET_WITHOUT_NODE_S
        feed.spin(quiet_s)
        before = counter_after(time.time()) if args.node else None
        feed.arrival["result"].clear()
        stamps: list[int] = []
        print("window start", flush=True)
        play(args.duration, stamps)
        print("window end", flush=True)
        feed.spin(quiet_s)
        after = counter_after(time.time()) if args.node else None
        report.update(
            published=stamps,
            result_arrivals={str(k): v for k, v in feed.arrival["result"].items()},
            node_frames_received=(None if before is None or after is None else after - before),
            node_stage_latency=_stage_latency(feed) if args.node else {},
        )
    finally:
        args.out.write_text(json.dumps(report))
        feed.node.destroy_node()
        rclpy.shutdown()
    return 0


def _stage_latency(feed: CameraFeed) -> dict[str, str]:
    """The node's latest ``latency_*`` values of /diagnostics (its receive-to-publish time)."""
    values = feed.diagnostic_values()
    return {key: value for key, value in values.items() if key.startswith("latency_")}


def subscribe(args: argparse.Namespace) -> int:
    """The plain subscriber process: record each image's arrival until ``--stop-file`` exists,
    then write ``{stamp_ns: arrival_s}`` to ``--out``."""
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CompressedImage, Image

    from allo_mrad_ros import interface
    from allo_mrad_ros.ros.messages import stamp_to_ns

    arrivals: dict[str, float] = {}

    def record(msg: Image | CompressedImage) -> None:
        arrivals[str(stamp_to_ns(msg.header.stamp))] = time.time()

    rclpy.init()
    node = rclpy.create_node("transport_subscriber")
    topic = interface.IMAGE_TOPIC + (interface.COMPRESSED_SUFFIX if args.compressed else "")
    kind = CompressedImage if args.compressed else Image
    qos = _reliable_qos() if args.reliable else qos_profile_sensor_data
    node.create_subscription(kind, topic, record, qos)
    try:
        while not args.stop_file.exists():
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        args.out.write_text(json.dumps(arrivals))
        node.destroy_node()
        rclpy.shutdown()
    return 0


def _reliable_qos() -> object:
    """The sensor-data QoS (keep last 5, volatile) made reliable."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

    return QoSProfile(
        history=qos_profile_sensor_data.history,
        depth=qos_profile_sensor_data.depth,
        durability=qos_profile_sensor_data.durability,
        reliability=ReliabilityPolicy.RELIABLE,
    )


@contextmanager
def _environment(environment: Mapping[str, str]) -> Iterator[None]:
    """``os.environ`` replaced for the duration (start_node passes it on)."""
    saved = dict(os.environ)
    os.environ.clear()
    os.environ.update(environment)
    try:
        yield
    finally:
        os.environ.clear()
        os.environ.update(saved)


def _role(role: str, *arguments: str) -> list[str]:
    return [sys.executable, "-m", "benchmarks.transport", role, *arguments]


def measure(
    setting: Setting,
    mode: str,
    frames: Path,
    *,
    duration_s: float,
    node: bool,
    work: Path,
    domain_id: int,
) -> list[dict]:
    """One run: publisher, node (unless ``node`` is False) and subscriber under ``setting``;
    the rows of each receiver."""
    from allo_mrad_ros import interface
    from allo_mrad_ros.ros.node_process import start_node, stop_node, wait_or_kill

    environment = setting_environment(os.environ, setting, domain_id)
    run = work / f"{setting.name}_{mode}"
    run.mkdir()
    # The image's message type and QoS, for both peers.
    flags = ["--compressed"] * setting.compressed + ["--reliable"] * setting.reliable
    processes: list[subprocess.Popen] = []
    node_process = None
    try:
        if node:
            parameters = [f"diagnostics_period_s:={DIAGNOSTICS_PERIOD_S}"]
            if setting.compressed:
                parameters.append("image_transport:=compressed")
            if setting.reliable:
                topic = interface.IMAGE_TOPIC
                parameters.append(f"qos_overrides.{topic}.subscription.reliability:=reliable")
            with _environment(environment):
                node_process = start_node(run / "node.log", *parameters)
        stop_file = run / "stop"
        with (run / "subscriber.log").open("w") as log:
            subscriber = subprocess.Popen(
                _role("subscribe", "--out", str(run / "subscriber.json"), "--stop-file",
                      str(stop_file), *flags),
                env=environment, stdout=log, stderr=subprocess.STDOUT, cwd=REPO,
            )  # fmt: skip
        processes.append(subscriber)
        with (run / "publisher.log").open("w") as log:
            publisher = subprocess.Popen(
                _role("publish", "--mode", mode, "--duration", str(duration_s), "--frames",
                      str(frames), "--out", str(run / "publisher.json"), *flags,
                      *([] if node else ["--no-node"])),
                env=environment, stdout=subprocess.PIPE, stderr=log, text=True, cwd=REPO,
            )  # fmt: skip
        processes.append(publisher)
        receivers = {"subscriber": subscriber.pid}
        if node_process is not None:
            receivers["node"] = node_process.pid
        pids = {"publisher": publisher.pid, **receivers}
        samples: dict[str, tuple[float, dict[str, float]]] = {}
        load = []
        assert publisher.stdout is not None
        for line in publisher.stdout:
            if line.startswith("window "):
                moment = line.split()[1]
                cpu = {name: process_cpu_seconds(pid) for name, pid in pids.items()}
                samples[moment] = (time.monotonic(), cpu)
                load.append(os.getloadavg()[0])
        publisher.wait(timeout=60)
        stop_file.touch()
        if not wait_or_kill(subscriber, 30):
            # Hung on its way out (seen with LARGE_DATA on the Jazzy wheels): its arrivals
            # were written before rclpy shut down, so they count.
            if not (run / "subscriber.json").is_file():
                raise TransportBenchError(
                    f"subscriber of {setting.name} {mode} hung before writing its arrivals; "
                    f"see {run / 'subscriber.log'}"
                )
            print(f"  ({setting.name} {mode}: the subscriber hung on exit and was killed)")
        if publisher.returncode or "end" not in samples:
            raise TransportBenchError(
                f"publisher of {setting.name} {mode} failed (exit {publisher.returncode}); "
                f"see {run / 'publisher.log'}"
            )
        if subscriber.returncode and subscriber.returncode != -9:
            raise TransportBenchError(
                f"subscriber of {setting.name} {mode} exited with {subscriber.returncode}; "
                f"see {run / 'subscriber.log'}"
            )
        if node_process is not None and node_process.poll() is not None:
            raise TransportBenchError(
                f"node of {setting.name} {mode} exited with {node_process.returncode}; "
                f"see {run / 'node.log'}"
            )
    finally:
        for process in processes:
            if process.poll() is None:
                process.kill()
                process.wait()
        if node_process is not None:
            stop_node(node_process)
    published_report = json.loads((run / "publisher.json").read_text())
    published = published_report["published"]
    (t0, cpu0), (t1, cpu1) = samples["start"], samples["end"]
    cpu = {name: cpu_percent(cpu0[name], cpu1[name], t1 - t0) for name in pids}
    common = {
        "message_bytes": max(published_report["message_bytes"]),
        "rate_published_hz": len(published) / (t1 - t0),
        "load_average": load,
        "description": setting.description,
    }
    arrivals = {int(k): v for k, v in json.loads((run / "subscriber.json").read_text()).items()}
    rows = [
        make_row(
            setting=setting.name,
            mode=mode,
            receiver="subscriber",
            published=published,
            received=list(arrivals),
            arrivals=arrivals,
            cpu_publisher_percent=cpu["publisher"],
            cpu_receiver_percent=cpu["subscriber"],
            latency_basis="image stamp to the subscriber's callback",
            **common,
        )
    ]
    if node_process is not None:
        results = {int(k): v for k, v in published_report["result_arrivals"].items()}
        received = published_report["node_frames_received"]
        if received is None:
            raise TransportBenchError(
                f"no /diagnostics from the node of {setting.name} {mode}; see {run / 'node.log'}"
            )
        row = make_row(
            setting=setting.name,
            mode=mode,
            receiver="node",
            published=published,
            # The node counts frames, not stamps: the first `received` stand for them.
            received=published[:received],
            arrivals=results,
            cpu_publisher_percent=cpu["publisher"],
            cpu_receiver_percent=cpu["node"],
            latency_basis="image stamp to the frame's ~/result (includes detection)",
            processed_ratio=len(set(published).intersection(results)) / len(published),
            node_latency=published_report["node_stage_latency"],
            **common,
        )
        rows.append(row)
    return rows


def render_frames(mode: str, path: Path, seed: int = 0) -> Path:
    """The still pose's two images at ``mode``'s size with sensor noise, saved to ``path``."""
    from benchmarks.node import camera_of
    from benchmarks.node_session import still_frames

    width, height, _ = MODES[mode]
    pose, (clean, with_object) = still_frames(camera_of(width, height))
    rng = np.random.default_rng(seed)

    def noisy(image: np.ndarray) -> np.ndarray:
        noise = rng.normal(0.0, NOISE_SIGMA, image.shape)
        return np.clip(image + noise, 0, 255).astype(np.uint8)

    np.savez(path, pose=pose, clean=noisy(clean), with_object=noisy(with_object))
    return path


def profile_setting(path: Path) -> Setting:
    """A setting of one's own: Fast DDS profile file ``path``, named ``profile:<file stem>``."""
    if not path.is_file():
        raise TransportBenchError(f"{path}: no such profile file")
    return Setting(
        f"profile:{path.stem}",
        f"FASTDDS_DEFAULT_PROFILES_FILE={path}",
        profile_variables(path.resolve()),
    )


def bench(
    modes: Sequence[str], settings: Sequence[Setting], *, duration_s: float, node: bool, work: Path
) -> dict:
    """Every setting for each mode (settings interleaved within a mode); the report."""
    rows = []
    domain_id = process_domain()
    for mode in modes:
        frames = render_frames(mode, work / f"frames_{mode}.npz")
        for setting in settings:
            before = os.getloadavg()
            mode_rows = measure(
                setting, mode, frames, duration_s=duration_s, node=node, work=work,
                domain_id=domain_id,
            )  # fmt: skip
            for row in mode_rows:
                row["load_average_before"] = list(before)
            print(table(mode_rows).split("\n", 1)[1], flush=True)
            rows.extend(mode_rows)
    return {
        "rows": rows,
        "duration_s": duration_s,
        "deployment_setting": DEPLOYMENT_SETTING,
        "settings": {setting.name: setting.description for setting in settings},
        "noise_sigma": NOISE_SIGMA,
        **machine_facts(),
    }


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point (the orchestrator, or one of its processes' roles)."""
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] in ("publish", "subscribe"):
        return _role_main(argv)
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=30.0, help="seconds per run")
    add_names_option(parser, "--modes", MODES, what="mode", help="camera modes")
    add_names_option(
        parser,
        "--settings",
        SETTINGS,
        what="setting",
        help="transport settings (none: only the --profile ones)",
        allow_empty=True,
    )
    parser.add_argument(
        "--profile",
        type=Path,
        action="append",
        default=[],
        help="also measure under this Fast DDS profile file (repeatable; setting profile:<stem>)",
    )
    parser.add_argument(
        "--no-node", action="store_true", help="publisher and plain subscriber only"
    )
    parser.add_argument(
        "--allow-network",
        action="store_true",
        help="run although interfaces besides loopback exist (DDS traffic may leave the host)",
    )
    parser.add_argument("--out", type=Path, default=Path("reports/bench_transport.json"))
    args = parser.parse_args(argv)
    modes, names = args.modes, args.settings
    try:
        settings = [SETTINGS[n] for n in names] + [profile_setting(p) for p in args.profile]
    except TransportBenchError as error:
        parser.error(str(error))
    interfaces = other_interfaces()
    if interfaces and not args.allow_network:
        parser.error(
            f"network interfaces besides loopback ({', '.join(interfaces)}): the defaults and "
            "LARGE_DATA would reach them; run in a private network namespace (make "
            "bench-transport) or pass --allow-network"
        )
    work = Path(tempfile.mkdtemp(prefix="bench_transport_"))
    print(
        f"{len(settings)} settings x {len(modes)} modes, {args.duration:g} s each; "
        f"load average {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs); logs in {work}"
    )
    print(table([]))
    report = bench(modes, settings, duration_s=args.duration, node=not args.no_node, work=work)
    deployment = SETTINGS[DEPLOYMENT_SETTING].description
    print(f"* the deployment setting ({DEPLOYMENT_SETTING}: {deployment})")
    return finish(args.out, report)


def _role_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog=f"benchmarks.transport {argv[0]}")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--compressed", action="store_true")
    parser.add_argument("--reliable", action="store_true")
    if argv[0] == "publish":
        parser.add_argument("--mode", choices=list(MODES), required=True)
        parser.add_argument("--duration", type=float, required=True)
        parser.add_argument("--frames", type=Path, required=True)
        parser.add_argument("--no-node", dest="node", action="store_false")
        return publish(parser.parse_args(argv[1:]))
    parser.add_argument("--stop-file", type=Path, required=True)
    return subscribe(parser.parse_args(argv[1:]))


if __name__ == "__main__":
    sys.exit(main())
