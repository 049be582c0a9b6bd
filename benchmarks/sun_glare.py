"""The Sun's glare (``sun_glare``): the frames with the Sun in the image, per factor.

Only a frame with the Sun's computed position in or next to its image can change (elsewhere
the rule does nothing), so only those frames are detected (:meth:`View.sun_pixel
<allo_mrad_ros.view.View.sun_pixel>`, within :data:`MARGIN` of the image), each reference
rendered once and detected with every factor in turn (all see the same machine load). Per
factor it prints the normal frames flagged; the anomalous frames flagged and those of them
whose mask touches the anomaly (*found on the object*: a frame flagged for the glare next to
a missed object is not found); the frames flagged *off the object* (normal ones, and
anomalous ones whose mask misses the anomaly: flagged for something else, here the glare);
the anomaly pixels masked; and the median time of ``detect()``.

    python -m benchmarks.sun_glare data/objects:val data/bench_val:val data/objects_pt_hub \\
        --factors 0,1,2,3,4,5,6,8,10,12,16
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from allo_mrad_ros.detector import MradParams, detect
from allo_mrad_ros.detector.params import params_from
from allo_mrad_ros.evaluation.sources import SequenceSource, open_sequence
from allo_mrad_ros.pipeline import Pipeline, PipelineConfig
from allo_mrad_ros.sequence.model import MASK_ANOMALY
from allo_mrad_ros.view import View
from benchmarks import finish

MARGIN = 0.05
"""How far outside the image, as a fraction of its size, the Sun may be for a frame to be
measured: more than the rule reaches (:func:`~allo_mrad_ros.detector.highlights.sun_reach`,
1/64 of the shorter side)."""


@dataclass
class SunCounts:
    """One factor's figures on one sequence split's frames with the Sun in the image."""

    normal: int = 0
    normal_flagged: int = 0
    anomalous: int = 0
    anomalous_flagged: int = 0
    found_on_object: int = 0
    anomaly_pixels: int = 0
    anomaly_pixels_masked: int = 0
    detect_ms: list[float] = field(default_factory=list)


def _sun_frames(source: SequenceSource, indices: list[int]) -> list[int]:
    """The frames of ``indices`` with the Sun's computed position in the image, or outside
    it by less than :data:`MARGIN` of its size (the rule reaches a little beyond the edge)."""
    camera = source.camera
    dx, dy = MARGIN * camera.width, MARGIN * camera.height
    kept = []
    for index in indices:
        pixel = View.of_frame(source.sequence.frames[index]).sun_pixel(camera)
        if pixel is None:
            continue
        x, y = pixel
        if -dx <= x < camera.width + dx and -dy <= y < camera.height + dy:
            kept.append(index)
    return kept


def measure(path: str, split: str | None, factors: list[float], base: MradParams) -> dict:
    """Per factor, the :class:`SunCounts` of ``path``'s ``split`` (every frame when None)."""
    source = open_sequence(path)
    indices = source.select(split) if split else list(range(len(source.sequence.frames)))
    frames = _sun_frames(source, indices)
    params = {factor: base.replace(sun_glare=factor) for factor in factors}
    counts = {factor: SunCounts() for factor in factors}
    config = PipelineConfig(methods=("MRAD",), params=base)
    with Pipeline.open(source.camera, mesh=source.mesh, config=config) as pipeline:
        for frame in source.frames(frames):
            reference = pipeline.render(frame.view)
            sun = frame.view.sun_pixel(source.camera)
            truth = frame.mask == MASK_ANOMALY
            for factor in factors:
                start = time.perf_counter()
                result = detect(frame.image, reference, params[factor], sun_pixel=sun)
                tally = counts[factor]
                tally.detect_ms.append(1e3 * (time.perf_counter() - start))
                if not frame.is_anomalous:
                    tally.normal += 1
                    tally.normal_flagged += int(result.anomalous)
                    continue
                masked = int(np.count_nonzero(result.mask[truth]))
                tally.anomalous += 1
                tally.anomalous_flagged += int(result.anomalous)
                tally.found_on_object += int(result.anomalous and masked > 0)
                tally.anomaly_pixels += int(np.count_nonzero(truth))
                tally.anomaly_pixels_masked += masked
    per_factor = {}
    for factor, tally in counts.items():
        figures = asdict(tally)
        times = figures.pop("detect_ms")
        figures["detect_ms_median"] = float(np.median(times)) if times else None
        per_factor[str(factor)] = figures
    return {"frames": len(frames), "per_factor": per_factor}


def table(name: str, report: dict) -> str:
    """One sequence's figures as Markdown rows."""
    rows = [
        f"{name}: {report['frames']} frames with the Sun in the image",
        "| sun_glare | normal flagged | anomalous flagged | found on the object | "
        "flagged off the object | anomaly px masked | detect ms (median) |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for factor, c in report["per_factor"].items():
        off = c["normal_flagged"] + c["anomalous_flagged"] - c["found_on_object"]
        rows.append(
            f"| {factor} | {c['normal_flagged']}/{c['normal']} | "
            f"{c['anomalous_flagged']}/{c['anomalous']} | "
            f"{c['found_on_object']}/{c['anomalous']} | {off}/{c['normal'] + c['anomalous']} | "
            f"{c['anomaly_pixels_masked']}/{c['anomaly_pixels']} | "
            f"{c['detect_ms_median'] or 0:.1f} |"
        )
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequences", nargs="+", metavar="SEQ", help="PATH or PATH:SPLIT")
    parser.add_argument("--factors", default="0,1,2,3,4,6")
    parser.add_argument("--profile", default="default")
    parser.add_argument("--out", type=Path, default=Path("reports/sun_glare.json"))
    args = parser.parse_args(argv)
    factors = [float(v) for v in args.factors.split(",")]
    base = params_from(args.profile, [])
    report = {}
    for item in args.sequences:
        path, _, split = item.partition(":")
        report[item] = measure(path, split or None, factors, base)
        print(table(item, report[item]), flush=True)
    return finish(args.out, {"profile": args.profile, "sequences": report})


if __name__ == "__main__":
    sys.exit(main())
