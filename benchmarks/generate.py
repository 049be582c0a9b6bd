"""Benchmark of the ALLO-like generator (``allo-synth generate``) at 1920x1080.

Generates a sequence from a preset (by default ``demo`` scaled to 40 frames) into a
temporary folder and reports the throughput in frames per minute, plus the share of a frame
spent rendering and post-processing (synthesis) against writing PNGs, measured on a second
pass over a few frames. Writes a JSON report.

Usage: ``python -m benchmarks.generate --out reports/bench_generate.json``
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from allo_mrad_ros.resources import share_path
from allo_mrad_ros.sequence.png import encode_png
from allo_mrad_ros.synth.config import PRESETS, preset
from allo_mrad_ros.synth.frames import FrameSynthesizer
from allo_mrad_ros.synth.generator import generate
from allo_mrad_ros.synth.planning import plan_frames
from benchmarks import finish, machine_facts


def stage_times(name: str, frames: int, seed: int) -> dict[str, float]:
    """Median milliseconds per frame of synthesis and of PNG encoding (image and mask)."""
    config = preset(name).with_frames(frames)
    synthesizer = FrameSynthesizer(config, seed, share_path("meshes", "station.glb"))
    synth_ms, png_ms = [], []
    try:
        for plan in plan_frames(config, seed):
            start = time.perf_counter()
            output = synthesizer.synthesize(plan)
            synth_ms.append(1000 * (time.perf_counter() - start))
            start = time.perf_counter()
            encode_png(output.image, config.png_compression)
            encode_png(output.mask, config.png_compression)
            png_ms.append(1000 * (time.perf_counter() - start))
    finally:
        synthesizer.close()
    return {
        "synthesis_ms_median": float(np.median(synth_ms)),
        "png_ms_median": float(np.median(png_ms)),
    }


def run(name: str, frames: int, seed: int, jobs: int, stage_frames: int) -> dict:
    """Generate once and time it; then time the stages on a few frames."""
    config = preset(name).with_frames(frames)
    with tempfile.TemporaryDirectory() as folder:
        report = generate(config, Path(folder) / "seq", seed, jobs=jobs, progress=False)
    return {
        "preset": name,
        "size": [config.width, config.height],
        "frames": report.frames,
        "seed": seed,
        "jobs": jobs,
        "seconds": report.seconds,
        "frames_per_minute": report.frames_per_minute,
        "composition": report.composition,
        **stage_times(name, stage_frames, seed),
        **machine_facts(),
    }


def format_report(report: dict) -> str:
    """The printed summary: throughput, then the per-frame stage medians."""
    width, height = report["size"]
    return (
        f"{report['preset']}: {report['frames']} frames at {width}x{height} in "
        f"{report['seconds']:.1f} s = {report['frames_per_minute']:.1f} frames/min "
        f"({report['jobs']} job(s), {report['cpu_count']} CPUs)\n"
        f"per frame: synthesis {report['synthesis_ms_median']:.0f} ms, "
        f"PNG encoding {report['png_ms_median']:.0f} ms (medians)"
    )


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark, print the figures and write the JSON report."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path("reports/bench_generate.json"))
    parser.add_argument("--preset", choices=tuple(PRESETS), default="demo")
    parser.add_argument("--frames", type=int, default=40, help="frames to generate")
    parser.add_argument("--stage-frames", type=int, default=8, help="frames for the stage times")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=1)
    args = parser.parse_args(argv)
    if min(args.frames, args.stage_frames, args.jobs) < 1 or args.seed < 0:
        parser.error("--frames, --stage-frames and --jobs must be >= 1, --seed >= 0")
    report = run(args.preset, args.frames, args.seed, args.jobs, args.stage_frames)
    print(format_report(report))
    return finish(args.out, report)


if __name__ == "__main__":
    raise SystemExit(main())
