"""The bad-input sweep (``make sweep``): ~180 kinds of bad input against the node,
``allo-bag`` and ``allo-synth``, each classified as clean, traceback, crash, partial output,
silent wrong or unclear error; prints the table and the count per verdict and writes
``sweep.json`` / ``sweep.md``. Exit status 1 when any case is not clean, so a regression fails.

Usage: ``python test/sweep/sweep.py [--quick] [--only REGEX] [--out reports/sweep]``

The node runs as its own process with DDS on loopback (``config/fastdds_loopback.xml``; run it
under ``$(ISOLATED)`` as the Makefile does). ``--quick`` runs the reduced set of ``make test``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parent), str(HERE.parent.parent)]  # the root: harness/
REPO = HERE.parent.parent
os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
from allo_mrad_ros.ros.node_process import use_loopback_profile  # noqa: E402
from harness.dds import process_domain  # noqa: E402

use_loopback_profile(profile=REPO / "config" / "fastdds_loopback.xml")
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
os.environ.setdefault("ROS_DOMAIN_ID", str(process_domain()))

from sweep_verdicts import CLEAN, Outcome, counts, table_text, write_reports  # noqa: E402


def build_fixtures(work: Path, baseline: bool, long: bool) -> dict:
    """The tiny sequence, its bag, a tiny ALLO split, (optionally) a longer sequence and the
    intact bag's metrics."""
    import cv2
    import numpy as np
    from rosbag_fixtures import write_tiny_sequence

    from allo_mrad_ros.resources import share_path
    from rosbag_tools.writer import write_bag

    seq = write_tiny_sequence(work / "seq", train=1)
    bag = work / "bag"
    write_bag(seq, bag)
    allo = work / "ALLO" / "test"
    folder = allo / "Camera0"
    (folder / "images").mkdir(parents=True)
    (folder / "masks").mkdir()
    for index, name in enumerate(["1_normal_1.png", "2_normal_10.png", "3_normal_5.png"]):
        cv2.imwrite(str(folder / "images" / name), np.full((1080, 1920, 3), 30 * index, np.uint8))
        cv2.imwrite(str(folder / "masks" / name), np.ones((1080, 1920), np.uint8))
    fixtures = {
        "seq": seq,
        "bag": bag,
        "mcap": next(bag.glob("*.mcap")),
        "allo": allo,
        "mesh": share_path("meshes", "station.glb"),
        "baseline": {},
        "bigseq": _long_sequence(work / "bigseq") if long else None,
    }
    if baseline:
        report = work / "baseline"
        subprocess.run(
            [
                sys.executable,
                "-m",
                "rosbag_tools",
                "evaluate",
                str(bag),
                "--out",
                str(report),
                "--methods",
                "MRAD",
                "--overlays",
                "0",
                "--quiet",
            ],
            check=True,
            capture_output=True,
        )
        fixtures["baseline"] = json.loads((report / "metrics.json").read_text())
    return fixtures


def _long_sequence(root: Path, frames: int = 40) -> Path:
    """Noise frames at 640x360: a bag write of a few seconds, for a signal to land in."""
    import numpy as np

    from allo_mrad_ros.camera import ALLO_INTRINSICS
    from allo_mrad_ros.sequence import SequenceMeta, SequenceWriter

    camera = ALLO_INTRINSICS.scaled(1.0 / 3.0)
    rng = np.random.default_rng(0)
    meta = SequenceMeta(name="long", camera=camera, rate_hz=10.0)
    with SequenceWriter(root, meta) as writer:
        for index in range(frames):
            writer.add_frame(
                split="test" if index % 2 else "train",
                camera=0,
                image=rng.integers(0, 256, (camera.height, camera.width, 3), dtype=np.uint8),
                mask=np.ones((camera.height, camera.width), np.uint8),
                position=[-30.0, -12.0, 6.0],
                quaternion=[0.0, 0.0, 0.0, 1.0],
                sun_direction=[0.6, 0.0, 0.8],
            )
    return root


def selected(cases: list, quick: bool, only: str | None) -> list:
    chosen = [c for c in cases if c.quick or not quick]
    if only:
        chosen = [c for c in chosen if re.search(only, f"{getattr(c, 'group', 'node')}: {c.name}")]
    return chosen


def run_cli(work: Path, quick: bool, only: str | None, jobs: int) -> list[Outcome]:
    from sweep_cli_cases import cli_cases, same_metrics
    from sweep_cli_output_cases import output_cases
    from sweep_run import can_mount, run_case

    cases = selected(cli_cases() + output_cases(), quick, only)
    if not cases:
        return []
    fixtures = build_fixtures(
        work / "fixtures",
        baseline=any(c.check is same_metrics for c in cases),
        long=any("{bigseq}" in " ".join(c.argv) for c in cases),
    )
    mountable = can_mount()
    with ThreadPoolExecutor(jobs) as pool:
        return list(pool.map(lambda c: run_case(c, fixtures, work / "cases", mountable), cases))


def run_node(work: Path, quick: bool, only: str | None, jobs: int) -> list[Outcome]:
    import rclpy
    from sweep_node import Live, run_case, run_param, run_start
    from sweep_node_cases import param_cases, run_cases, start_cases
    from sweep_node_deploy_cases import deploy_run_cases, deploy_start_cases

    work.mkdir(parents=True, exist_ok=True)
    outcomes: list[Outcome] = []
    every_start = start_cases(work) + deploy_start_cases(work)
    starts = [c for c in selected(every_start, quick, None) if _wanted(only, "node start", c)]
    with ThreadPoolExecutor(jobs) as pool:
        outcomes += list(pool.map(run_start, starts))
    every_run = run_cases() + deploy_run_cases()
    running = [c for c in selected(every_run, quick, None) if _wanted(only, "node running", c)]
    params = [
        c for c in selected(param_cases(), quick, None) if _wanted(only, "node parameter change", c)
    ]
    if not running and not params:
        return outcomes
    rclpy.init()
    live = Live(work)
    try:
        if live.process_one(120.0) is None:
            raise RuntimeError(f"the node processes no frame; see {live.log_path}")
        outcomes += [run_case(live, case) for case in running]
        outcomes += [run_param(live, case) for case in params]
    finally:
        live.close()
        rclpy.shutdown()
    return outcomes


def _wanted(only: str | None, group: str, case: object) -> bool:
    return not only or re.search(only, f"{group}: {case.name}") is not None


def sweep(quick: bool = False, only: str | None = None, jobs: int = 2) -> list[Outcome]:
    """Run the sweep (or its quick subset); return every case's outcome."""
    with tempfile.TemporaryDirectory(prefix="allo-sweep-") as temporary:
        work = Path(temporary)
        outcomes = run_cli(work / "cli", quick, only, jobs)
        outcomes += run_node(work / "node", quick, only, jobs)
    return outcomes


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="the reduced set of make test")
    parser.add_argument("--only", help="run only cases whose 'group: name' matches")
    parser.add_argument("--jobs", type=int, default=2, help="command-line cases at once")
    parser.add_argument("--out", type=Path, default=REPO / "reports" / "sweep")
    args = parser.parse_args(argv)
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        # Started in the background by a shell: SIGINT is ignored and the commands under test
        # would inherit that, so a SIGINT case would test nothing. Give them the default.
        signal.signal(signal.SIGINT, signal.default_int_handler)
    start = time.monotonic()
    outcomes = sweep(args.quick, args.only, args.jobs)
    print(table_text(outcomes))
    print(f"{time.monotonic() - start:.0f} s")
    write_reports(outcomes, args.out)
    print(f"report: {args.out / 'sweep.md'}, {args.out / 'sweep.json'}")
    return 0 if counts(outcomes)[CLEAN] == len(outcomes) else 1


if __name__ == "__main__":
    sys.exit(main())
