"""Running the node's cases of the sweep through real DDS on loopback.

Start-up cases run the node process with an invalid parameter and read its exit and its
output. Running cases share one node process (``allo_mrad_ros.ros.node``) driven by a
:class:`~harness.feed.CameraFeed` in this process: each case publishes its bad input,
waits for the node to count it in ``/diagnostics``, and then checks that a good frame is
still processed. The node's log is a file; a case reads what the node wrote during it.
"""

from __future__ import annotations

import itertools
import os
import re
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import psutil
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import SetParameters
from sweep_verdicts import CLEAN, CRASH, SILENT, TRACEBACK, UNCLEAR, Outcome, classify_exit

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.ros.node_process import start_node, stop_node
from harness.dds import current_domain, domain_apart
from harness.feed import CameraFeed

HERE = Path(__file__).resolve().parent
INTRINSICS = CameraIntrinsics(320, 180, 222.2, 222.2, 160.0, 90.0)
POSE = look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0])
IMAGE = np.full((180, 320, 3), 40, np.uint8)
# No input-age bound: on a loaded machine a frame older than the default 0.1 s when taken is
# dropped before its bad input is looked at, and the case's counter would not grow.
NODE_ARGS = (
    "diagnostics_period_s:=0.2",
    "reference_scale:=0.25",
    "input_timeout_s:=5.0",
    "max_input_age_s:=0.0",
)
WAIT_S = 20.0
# Largest growth of the node's resident memory when an oversize image comes again.
RSS_BOUND_MB = 32.0
# Largest growth per renderer rebuild: unreleased, a rebuild kept about 30 KB.
REBUILD_BOUND_KB = 12.0
# Rebuilds between two readings of the node's RSS.
REBUILD_SAMPLE = 50
# Process cases run two at a time: each in a DDS domain of its own.
_DOMAINS = itertools.count(1)


@dataclass(frozen=True)
class StartCase:
    """The node started with ``arguments``: refused in one line matching ``keyword`` (exit
    non-zero, no traceback), or, with ``starts``, running and having said ``keyword``."""

    name: str
    arguments: tuple[str, ...]
    keyword: str
    starts: bool = False
    quick: bool = False


@dataclass(frozen=True)
class RunCase:
    """Bad input to the running node: ``send(live, stamp)`` publishes it. ``counter`` (a
    regular expression over ``/diagnostics`` keys) must grow and ``keyword`` appear in the
    log; with ``accepted`` the frame must instead be processed; with ``either`` both are
    clean. After the case a good frame must still come through."""

    name: str
    send: Callable[[Live, int], None]
    counter: str = ""
    keyword: str = ""
    accepted: bool = False
    either: bool = False
    quick: bool = False
    rss_bound: bool = False
    # With a count: the input makes the node rebuild its renderer for every frame; the RSS
    # growth per rebuild over the later two thirds must stay below REBUILD_BOUND_KB.
    rebuilds: int = 0
    # The image itself is bad (it must not be processed); else the bad message is a side
    # input (camera_info, pose, Sun, bodies): refused and counted, while frames go on with
    # the last valid one.
    frame_is_bad: bool = True


@dataclass(frozen=True)
class ParamCase:
    """A parameter change over the node's set_parameters service: rejected with a reason
    matching ``keyword``, or (``accepted``) applied."""

    name: str
    parameter: str
    value: object  # rcl_interfaces ParameterValue
    keyword: str = ""
    accepted: bool = False
    quick: bool = False


@dataclass(frozen=True)
class ProcessCase:
    """A script of this folder that runs node processes of its own (shutdowns under a feed,
    a second signal, DDS delivery), in a DDS domain of its own: exit 0 is clean, else its
    last line says what went wrong, with the verdict ``failure``."""

    name: str
    argv: tuple[str, ...]
    failure: str = TRACEBACK
    quick: bool = False
    timeout_s: float = 900.0


class Live:
    """The running node process and the feed talking to it."""

    def __init__(self, work: Path) -> None:
        self.log_path = work / "node.log"
        self.feed = CameraFeed(INTRINSICS)
        self.process = start_node(self.log_path, *NODE_ARGS)
        self.psutil = psutil.Process(self.process.pid)
        self.stamp = 1_900_000_000 * 10**9
        if not self.feed.wait_for_node(120.0):
            raise RuntimeError(f"the node did not subscribe; see {self.log_path}")

    def next_stamp(self) -> int:
        self.stamp += 10**7
        return self.stamp

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def alive(self) -> bool:
        return self.process.poll() is None

    def rss_mb(self) -> float:
        return self.psutil.memory_info().rss / 2**20

    def values(self) -> dict[str, str]:
        """The /diagnostics values published after now."""
        seen = len(self.feed.diagnostics)
        self.feed.wait_for(lambda: len(self.feed.diagnostics) > seen, 5.0)
        return self.feed.diagnostic_values()

    def process_one(self, timeout: float = 60.0) -> int | None:
        """Publish good frames until one is processed; return its stamp."""
        end = time.monotonic() + timeout
        while time.monotonic() < end and self.alive():
            stamp = self.next_stamp()
            self.feed.publish_frame(stamp, IMAGE, POSE)
            if self.feed.wait_for(lambda s=stamp: s in self.feed.received["mask"], 1.5):
                return stamp
        return None

    def close(self) -> None:
        stop_node(self.process)
        self.feed.node.destroy_node()


def _grown(before: dict[str, str], after: dict[str, str], pattern: str) -> list[str]:
    return [
        key
        for key, value in after.items()
        if re.fullmatch(pattern, key) and int(value) > int(before.get(key, "0") or 0)
    ]


def run_case(live: Live, case: RunCase) -> Outcome:
    """Publish the case's bad input and classify how the node dealt with it."""
    group = "node running"
    if not live.alive():
        return Outcome(group, case.name, CRASH, "node not running")
    if case.rebuilds:
        return run_rebuilds(live, case)
    start = len(live.log())
    before = live.values()
    rss_before = live.rss_mb()
    stamp = live.next_stamp()
    processed = False
    grown: list[str] = []
    end = time.monotonic() + WAIT_S
    while time.monotonic() < end and live.alive():
        case.send(live, stamp)
        live.feed.wait_for(lambda: stamp in live.feed.received["mask"], 1.5)
        processed = stamp in live.feed.received["mask"]
        grown = _grown(before, live.values(), case.counter) if case.counter else []
        if grown or case.rss_bound or (processed and (case.frame_is_bad or case.accepted)):
            break
    good = live.process_one()
    text = live.log()[start:]
    after = live.values()
    internal = _grown(before, after, "errors_internal")
    if not live.alive():
        return Outcome(group, case.name, CRASH, f"node exited with {live.process.returncode}")
    if "Traceback" in text or internal:
        line = next((x for x in text.splitlines() if "failed" in x or "Error" in x), "")
        return Outcome(group, case.name, TRACEBACK, line[:200])
    if good is None:
        return Outcome(group, case.name, CRASH, "no good frame processed after the case")
    if case.rss_bound:
        # Fast DDS keeps one reassembly buffer of the largest sample per subscription: the
        # first oversize image may cost its size once, but more must not cost more.
        first = live.rss_mb() - rss_before
        case.send(live, live.next_stamp())
        more = live.rss_mb() - rss_before - first
        if more > RSS_BOUND_MB or live.process_one() is None:
            return Outcome(group, case.name, SILENT, f"+{first:.0f} MB, then +{more:.0f} MB more")
        return Outcome(
            group, case.name, CLEAN, f"bounded: +{first:.0f} MB once, {more:+.0f} MB after more"
        )
    if case.accepted or (case.either and processed):
        if processed:
            return Outcome(group, case.name, CLEAN, "accepted and processed")
        return Outcome(group, case.name, UNCLEAR, f"valid input not processed; counters {grown}")
    if processed and case.frame_is_bad:
        return Outcome(group, case.name, SILENT, "bad image processed as if valid")
    if not grown:
        return Outcome(group, case.name, SILENT, f"nothing counted matching /{case.counter}/")
    if case.keyword and not re.search(case.keyword, live.log()):
        return Outcome(group, case.name, UNCLEAR, f"log never says /{case.keyword}/ ({grown})")
    lines = [x for x in live.log().splitlines() if case.keyword and re.search(case.keyword, x)]
    return Outcome(group, case.name, CLEAN, (lines[-1] if lines else ", ".join(grown))[-200:])


def run_rebuilds(live: Live, case: RunCase) -> Outcome:
    """Send the case's frames one at a time (each waited for) and read the node's RSS every
    ``REBUILD_SAMPLE`` of them. A leak grows every interval alike, while the allocator and
    DDS grow their pools in steps now and then: the verdict is the median interval's growth,
    after the first third (warm-up)."""
    group = "node running"
    start = len(live.log())
    samples = []
    for index in range(case.rebuilds):
        if index % REBUILD_SAMPLE == 0:
            samples.append(live.rss_mb())
        stamp = live.next_stamp()
        case.send(live, stamp)
        live.feed.wait_for(lambda s=stamp: s in live.feed.received["mask"], 10.0)
    samples.append(live.rss_mb())
    text = live.log()[start:]
    rebuilt = text.count("renderer ready")
    good = live.process_one()
    if not live.alive():
        return Outcome(group, case.name, CRASH, f"node exited with {live.process.returncode}")
    if "Traceback" in text:
        return Outcome(group, case.name, TRACEBACK, "a traceback in the log")
    if good is None:
        return Outcome(group, case.name, CRASH, "no good frame processed after the case")
    if rebuilt < case.rebuilds * 0.9:
        return Outcome(group, case.name, UNCLEAR, f"only {rebuilt} rebuilds logged")
    later = np.diff(samples)[len(samples) // 3 :]
    per_rebuild = 1024 * float(np.median(later)) / REBUILD_SAMPLE
    detail = (
        f"{rebuilt} rebuilds; median {per_rebuild:+.1f} KB RSS per rebuild "
        f"(MB per {REBUILD_SAMPLE}: {' '.join(f'{x:+.1f}' for x in np.diff(samples))})"
    )
    if per_rebuild > REBUILD_BOUND_KB:
        return Outcome(group, case.name, SILENT, detail)
    return Outcome(group, case.name, CLEAN, detail)


def run_param(live: Live, case: ParamCase) -> Outcome:
    """Change a parameter over the service and classify the answer."""
    group = "node parameter change"
    feed = live.feed
    client = feed.node.create_client(SetParameters, "/mrad_detector/set_parameters")
    try:
        if not client.wait_for_service(timeout_sec=30.0):
            return Outcome(group, case.name, CRASH, "no set_parameters service")
        request = SetParameters.Request(
            parameters=[ParameterMsg(name=case.parameter, value=case.value)]
        )
        future = client.call_async(request)
        if not feed.wait_for(future.done, 30.0):
            return Outcome(group, case.name, CRASH, "set_parameters did not answer")
        result = future.result().results[0]
    finally:
        feed.node.destroy_client(client)
    if live.process_one() is None:
        return Outcome(group, case.name, CRASH, "no frame processed after the change")
    if case.accepted:
        if result.successful:
            return Outcome(group, case.name, CLEAN, "applied")
        return Outcome(group, case.name, UNCLEAR, f"valid value refused: {result.reason}")
    if result.successful:
        return Outcome(group, case.name, SILENT, "invalid value accepted")
    if case.keyword and not re.search(case.keyword, result.reason):
        return Outcome(group, case.name, UNCLEAR, f"reason does not match: {result.reason}")
    return Outcome(group, case.name, CLEAN, result.reason[:200])


def run_process(case: ProcessCase) -> Outcome:
    """Run the case's script; its exit status is the verdict, its last line the detail."""
    group = "node process"
    # Neither the domain of the node start cases beside it nor another process case's.
    domain = domain_apart(current_domain(), 17 * next(_DOMAINS))
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    # The tree under test where PYTHONPATH names one, else this one.
    env["PYTHONPATH"] = os.pathsep.join(
        filter(None, [env.get("PYTHONPATH"), str(HERE.parent.parent)])
    )
    try:
        done = subprocess.run(
            [sys.executable, str(HERE / case.argv[0]), *case.argv[1:]],
            capture_output=True,
            text=True,
            timeout=case.timeout_s,
            env=env,
        )
    except subprocess.TimeoutExpired:
        return Outcome(group, case.name, CRASH, f"did not finish in {case.timeout_s:.0f} s")
    lines = (done.stdout + done.stderr).strip().splitlines()
    last = lines[-1] if lines else f"exit {done.returncode}"
    if "Traceback" in done.stderr:
        return Outcome(group, case.name, TRACEBACK, last[:200])
    return Outcome(group, case.name, CLEAN if done.returncode == 0 else case.failure, last[:200])


def run_start(case: StartCase | ProcessCase, timeout_s: float = 60.0) -> Outcome:
    """Start the node with the case's arguments; classify its exit and output."""
    if isinstance(case, ProcessCase):
        return run_process(case)
    group = "node start"
    argv = [sys.executable, "-m", "allo_mrad_ros.ros.node", "--ros-args"]
    argv += ["-p", "pose_source:=topic", *case.arguments]
    process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        stdout, stderr = process.communicate(timeout=timeout_s)
        returncode: int | None = process.returncode
    except subprocess.TimeoutExpired:
        process.terminate()
        stdout, stderr = process.communicate(timeout=30)
        returncode = None
    output = stdout + stderr
    if case.starts:
        if "Traceback" in output:
            return Outcome(group, case.name, TRACEBACK, output.strip().splitlines()[-1])
        if returncode is not None:
            return Outcome(group, case.name, UNCLEAR, f"exit {returncode}: {output[-200:]}")
        if not re.search(case.keyword, output):
            return Outcome(group, case.name, SILENT, f"started without saying /{case.keyword}/")
        return Outcome(
            group,
            case.name,
            CLEAN,
            "started; " + re.search(f".*{case.keyword}.*", output)[0][-160:],
        )
    if returncode is None:
        return Outcome(group, case.name, SILENT, "started with the invalid value")
    verdict, detail = classify_exit(returncode, output, case.keyword, [], True)
    return Outcome(group, case.name, verdict, detail)
