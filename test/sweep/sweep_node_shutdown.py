"""The node's shutdown under a feed, as its own process (the sweep runs it in a DDS domain of
its own; it also runs alone, under the private network namespace of ``make sweep``)::

    python test/sweep/sweep_node_shutdown.py shutdowns --runs 10 --signal SIGTERM
    python test/sweep/sweep_node_shutdown.py second-signal

``shutdowns``: the node started ``--runs`` times in a row, fed 1080p images at about 30 Hz
with every output subscribed, and stopped by the signal once it has published
``--settle`` masks: each run must exit 0 with no ERROR, FATAL or traceback in its log.
``second-signal``: a frame held in publishing (``ALLO_HOLD_AT=node-publish-stuck``) keeps
the orderly shutdown of a first SIGINT waiting; a second SIGINT must end the node at once
with status 130 and no traceback. Exit status 0 when clean; the last line says what failed.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rclpy

# The repository root, for harness/ (not installed).
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from allo_mrad_ros.camera import ALLO_INTRINSICS
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.ros.node_process import start_node
from allo_mrad_ros.staging import HOLD_AT, HOLD_MARKER
from harness.feed import CameraFeed

POSE = look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0])
OUTPUTS = ("score", "overlay", "result", "regions", "reference", "score/camera_info")
PERIOD_S = 1.0 / 30.0
LIMIT_S = 180.0
STOPPING = "stopping the processing threads"
# The worker's test hook (allo_mrad_ros.ros.worker.HOLD_PUBLISH_STUCK), named here so the
# script also runs against a tree without it.
HOLD_PUBLISH_STUCK = "node-publish-stuck"


def _problems(text: str) -> list[str]:
    return [
        line
        for line in text.splitlines()
        if any(word in line for word in ("ERROR", "FATAL", "Traceback", "context is invalid"))
    ]


def shutdowns(runs: int, signum: signal.Signals, settle: int, work: Path) -> int:
    """Start, feed and signal the node ``runs`` times; return how many runs were not clean."""
    feed = CameraFeed(ALLO_INTRINSICS, keep_messages=False)
    feed.set_outputs(OUTPUTS)
    image = np.random.default_rng(0).integers(0, 256, (1080, 1920, 3), dtype=np.uint8)
    stamp = 1_900_000_000 * 10**9
    failed = 0
    for run in range(1, runs + 1):
        log = work / f"node-{run}.log"
        process = start_node(log, "publish_overlay:=true", "publish_reference:=true")
        if not feed.wait_for_node(LIMIT_S):
            process.kill()
            print(f"run {run}: the node did not subscribe; see {log}", flush=True)
            return runs
        feed.arrival.clear()
        end, signalled = time.monotonic() + LIMIT_S, False
        while process.poll() is None and time.monotonic() < end:
            stamp += int(PERIOD_S * 1e9)
            feed.publish_frame(stamp, image, POSE)
            feed.spin(PERIOD_S)
            if not signalled and len(feed.arrival["mask"]) >= settle:
                process.send_signal(signum)
                signalled = True
        if process.poll() is None:
            process.kill()
        code = process.wait()
        problems = _problems(log.read_text())
        clean = signalled and code == 0 and not problems
        failed += not clean
        detail = "clean" if clean else (problems[0][:200] if problems else "no mask published")
        print(f"run {run}: exit {code}, {len(feed.arrival['mask'])} masks, {detail}", flush=True)
        if not clean:
            # The end of the node's log, so that a rare failure can be read afterwards.
            tail = log.read_text().splitlines()[-40:]
            print("\n".join(f"    | {line}" for line in tail), flush=True)
    feed.node.destroy_node()
    print(f"{runs - failed}/{runs} clean shutdowns by {signum.name}")
    return failed


def second_signal(work: Path) -> int:
    """SIGINT, then SIGINT again while the first's shutdown waits: 0 when the node ended at
    once with status 130 and no traceback."""
    feed = CameraFeed(ALLO_INTRINSICS.scaled(1 / 6), keep_messages=False)
    log, marker = work / "node.log", work / "held"
    argv = [sys.executable, "-m", "allo_mrad_ros.ros.node", "--ros-args", "-p"]
    env = {**os.environ, HOLD_AT: HOLD_PUBLISH_STUCK, HOLD_MARKER: str(marker)}
    process = subprocess.Popen(
        [*argv, "pose_source:=topic"], stdout=log.open("w"), stderr=subprocess.STDOUT, env=env
    )
    image = np.zeros((180, 320, 3), np.uint8)
    stamp, end = 1_900_000_000 * 10**9, time.monotonic() + LIMIT_S
    try:
        while not marker.exists() and process.poll() is None and time.monotonic() < end:
            stamp += 10**7
            feed.publish_frame(stamp, image, POSE)
            feed.spin(0.1)
        process.send_signal(signal.SIGINT)
        while STOPPING not in log.read_text() and process.poll() is None:
            if time.monotonic() > end:
                break
            time.sleep(0.01)
        process.send_signal(signal.SIGINT)
        code = process.wait(20.0)
    except subprocess.TimeoutExpired:
        process.kill()
        code = None
    text = log.read_text()
    feed.node.destroy_node()
    if code == 130 and "Traceback" not in text and "KeyboardInterrupt" not in text:
        print("second SIGINT: exit 130 at once, no traceback")
        return 0
    problems = _problems(text) + [x for x in text.splitlines() if "KeyboardInterrupt" in x]
    print(f"second SIGINT: exit {code}; {problems[0][:200] if problems else text[-200:]}")
    return 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    loop = commands.add_parser("shutdowns")
    loop.add_argument("--runs", type=int, default=10)
    loop.add_argument("--signal", choices=("SIGTERM", "SIGINT"), default="SIGTERM")
    loop.add_argument("--settle", type=int, default=3, help="masks published before the signal")
    commands.add_parser("second-signal")
    args = parser.parse_args(argv)
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        # Started in the background: the node would inherit an ignored SIGINT.
        signal.signal(signal.SIGINT, signal.default_int_handler)
    rclpy.init()
    try:
        with tempfile.TemporaryDirectory(prefix="allo-shutdown-") as folder:
            if args.command == "shutdowns":
                failed = shutdowns(
                    args.runs, signal.Signals[args.signal], args.settle, Path(folder)
                )
            else:
                failed = second_signal(Path(folder))
    finally:
        rclpy.shutdown()
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
