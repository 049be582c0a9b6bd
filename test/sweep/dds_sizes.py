"""Which images of a new, larger size reach another process: a plain rclpy publisher and
subscriber (best effort, as a camera driver publishes), no node.

Each run starts a subscriber process, then publishes 320x180 images between images of sizes
each larger than all before (``--repeats`` of each, ``--gap`` seconds apart) and reports,
per size, whether its first image arrived and how many of the others did. Run it with the
DDS profile under test (``FASTDDS_DEFAULT_PROFILES_FILE``) and in a private network
namespace, as the sweep does::

    unshare -n sh -c 'ip link set lo up && exec "$0" "$@"' \\
        python test/sweep/dds_sizes.py --runs 5

Exit status 0 when every first image of a size that fits the profile's shared-memory
segment arrived in every run, else 1.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SMALL = (320, 180)
# Sizes each larger than the last: 1080p, 4K, then past 512 and 1024 fragments of 64 KiB.
SIZES = ((1920, 1080), (3840, 2160), (3600, 3600), (4000, 4000), (4400, 4400), (4600, 4600))
# The shipped profile's shared-memory segment: larger messages are not expected to arrive.
SEGMENT_BYTES = 64 * 2**20
TOPIC = "/dds_sizes/image"
END = "end"


def _qos():
    from rclpy.qos import qos_profile_sensor_data

    return qos_profile_sensor_data


def subscribe(out: Path, limit_s: float) -> None:
    """Record the frame ids received until the end marker (or ``limit_s``) into ``out``."""
    import rclpy
    from sensor_msgs.msg import Image

    rclpy.init()
    node = rclpy.create_node("dds_sizes_subscriber")
    got: list[str] = []
    node.create_subscription(Image, TOPIC, lambda m: got.append(m.header.frame_id), _qos())
    end = time.monotonic() + limit_s
    while time.monotonic() < end and END not in got:
        rclpy.spin_once(node, timeout_sec=0.1)
    out.write_text(json.dumps(got))
    node.destroy_node()
    rclpy.shutdown()


def plan(repeats: int) -> list[tuple[str, tuple[int, int]]]:
    """``(frame id, size)`` in publishing order: smalls, then each size between smalls."""
    frames = []
    for index, size in enumerate(SIZES):
        frames += [(f"small-{index}-{r}", SMALL) for r in range(2)]
        frames += [(f"{size[0]}x{size[1]}-{r}", size) for r in range(repeats)]
    return frames


def publish(frames: list[tuple[str, tuple[int, int]]], gap_s: float, limit_s: float) -> None:
    import rclpy
    from sensor_msgs.msg import Image

    rclpy.init()
    node = rclpy.create_node("dds_sizes_publisher")
    publisher = node.create_publisher(Image, TOPIC, _qos())
    end = time.monotonic() + limit_s
    while publisher.get_subscription_count() == 0 and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.1)
    time.sleep(1.0)  # discovery complete both ways, so no image is lost to it
    payloads: dict[tuple[int, int], bytes] = {}
    for frame_id, (width, height) in [*frames, *[(END, (8, 8))] * 3]:
        data = payloads.setdefault((width, height), bytes(width * height * 3))
        msg = Image(width=width, height=height, encoding="rgb8", step=width * 3)
        msg.header.frame_id = frame_id
        msg.data = data
        publisher.publish(msg)
        time.sleep(gap_s)
    node.destroy_node()
    rclpy.shutdown()


def run_once(repeats: int, gap_s: float, limit_s: float) -> set[str]:
    """One run: a subscriber process and this one publishing; the frame ids received."""
    with tempfile.TemporaryDirectory(prefix="dds-sizes-") as folder:
        out = Path(folder) / "received.json"
        argv = [sys.executable, __file__, "--subscribe", str(out), "--limit", str(limit_s)]
        subscriber = subprocess.Popen(argv, env=dict(os.environ))
        try:
            publish(plan(repeats), gap_s, limit_s)
            subscriber.wait(limit_s)
        finally:
            if subscriber.poll() is None:
                subscriber.kill()
                subscriber.wait()
        return set(json.loads(out.read_text())) if out.exists() else set()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=3, help="images of each size")
    parser.add_argument("--gap", type=float, default=0.5, help="seconds between images")
    parser.add_argument("--limit", type=float, default=120.0, help="seconds a run may take")
    parser.add_argument("--subscribe", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.subscribe:
        subscribe(args.subscribe, args.limit)
        return 0
    profile = os.environ.get("FASTDDS_DEFAULT_PROFILES_FILE", "(Fast DDS defaults)")
    print(f"profile {profile}; {args.runs} runs, {args.repeats} images per size")
    runs = [run_once(args.repeats, args.gap, args.limit) for _ in range(args.runs)]
    lost_firsts = 0
    print(f"{'size':>10} {'MiB':>6}  first arrived  later arrived")
    for width, height in SIZES:
        mib = width * height * 3 / 2**20
        firsts = sum(f"{width}x{height}-0" in got for got in runs)
        later = sum(f"{width}x{height}-{r}" in got for got in runs for r in range(1, args.repeats))
        within = width * height * 3 < SEGMENT_BYTES
        lost_firsts += within and firsts < len(runs)
        print(
            f"{width}x{height:<5} {mib:6.1f}  {firsts:>5}/{len(runs):<7}  "
            f"{later:>5}/{len(runs) * (args.repeats - 1)}"
        )
    print(f"first images lost for {lost_firsts} size(s) within the segment")
    return 1 if lost_firsts else 0


if __name__ == "__main__":
    sys.exit(main())
