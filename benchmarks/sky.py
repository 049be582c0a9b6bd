"""Light in the sky the reference cannot draw, per value of its rule's parameter: the Sun's
glare (``sun_glare``) on the frames with the Sun in view, the limbs of the Earth and the Moon
(``body_margin``) on the frames with a body in view.

A rule acts only where the view puts its light in or next to the image, so only those frames
are detected (:meth:`View.sun_pixel <allo_mrad_ros.view.View.sun_pixel>` within
:data:`MARGIN` of the image; a disc of :meth:`View.body_discs
<allo_mrad_ros.view.View.body_discs>` reaching within it), each reference rendered once and
detected with every value in turn (all see the same machine load), the other rule at the
profile's value. Per value it prints the normal frames flagged; the anomalous frames flagged
and those of them whose mask touches the anomaly (*found on the object*: a frame flagged for
the glare next to a missed object is not found); the frames flagged *off the object* (normal
ones, and anomalous ones whose mask misses the anomaly: flagged for something else); the
anomaly pixels masked; and the median time of ``detect()``.

    python -m benchmarks.sky sun_glare data/objects:val data/bench_val:val \\
        data/objects_pt_hub --values 0,1,2,3,4,5,6,8,10,12,16
    python -m benchmarks.sky body_margin data/objects:val data/bench_val:val \\
        data/objects_pt_hub --values 0,0.5,1,1.5,2,3
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector import MradParams, detect
from allo_mrad_ros.detector.params import params_from
from allo_mrad_ros.evaluation.sources import open_sequence
from allo_mrad_ros.pipeline import Pipeline, PipelineConfig
from allo_mrad_ros.sequence.model import MASK_ANOMALY
from allo_mrad_ros.view import View
from benchmarks import finish

RULES = {"sun_glare": "the Sun", "body_margin": "a body"}
"""Each rule's parameter and what it needs in view."""

MARGIN = 0.05
"""How far outside the image, as a fraction of its size, the Sun or a body's disc may be for
a frame to be measured: more than either rule reaches (the Sun's glare
:func:`~allo_mrad_ros.detector.highlights.sun_reach`, 1/64 of the shorter side; a limb a few
reference pixels)."""


@dataclass
class FrameCounts:
    """One value's figures on one sequence split's frames with the rule's light in view."""

    normal: int = 0
    normal_flagged: int = 0
    anomalous: int = 0
    anomalous_flagged: int = 0
    found_on_object: int = 0
    anomaly_pixels: int = 0
    anomaly_pixels_masked: int = 0
    detect_ms: list[float] = field(default_factory=list)


def in_view(rule: str, view: View, camera: CameraIntrinsics) -> bool:
    """Whether ``rule``'s light is in or within :data:`MARGIN` of ``camera``'s image."""
    dx, dy = MARGIN * camera.width, MARGIN * camera.height
    if rule == "sun_glare":
        pixel = view.sun_pixel(camera)
        discs = [] if pixel is None else [(*pixel, 0.0)]
    else:
        discs = view.body_discs(camera)
    return any(
        -dx - r <= x < camera.width + dx + r and -dy - r <= y < camera.height + dy + r
        for x, y, r in discs
    )


def measure(rule: str, path: str, split: str | None, values: list[float], base: MradParams) -> dict:
    """Per value of ``rule``'s parameter, the :class:`FrameCounts` of ``path``'s ``split``
    (every frame when None)."""
    source = open_sequence(path)
    camera = source.camera
    indices = source.select(split) if split else list(range(len(source.sequence.frames)))
    frames = [i for i in indices if in_view(rule, View.of_frame(source.sequence.frames[i]), camera)]
    params = {value: base.replace(**{rule: value}) for value in values}
    counts = {value: FrameCounts() for value in values}
    config = PipelineConfig(methods=("MRAD",), params=base)
    with Pipeline.open(camera, mesh=source.mesh, config=config) as pipeline:
        for frame in source.frames(frames):
            reference = pipeline.render(frame.view)
            sky = {
                "sun_pixel": frame.view.sun_pixel(camera),
                "body_discs": frame.view.body_discs(camera),
            }
            truth = frame.mask == MASK_ANOMALY
            for value in values:
                start = time.perf_counter()
                result = detect(frame.image, reference, params[value], **sky)
                tally = counts[value]
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
    per_value = {}
    for value, tally in counts.items():
        figures = asdict(tally)
        times = figures.pop("detect_ms")
        figures["detect_ms_median"] = float(np.median(times)) if times else None
        per_value[str(value)] = figures
    return {"frames": len(frames), "per_value": per_value}


def table(rule: str, name: str, report: dict) -> str:
    """One sequence's figures as Markdown rows."""
    rows = [
        f"{name}: {report['frames']} frames with {RULES[rule]} in view",
        f"| {rule} | normal flagged | anomalous flagged | found on the object | "
        "flagged off the object | anomaly px masked | detect ms (median) |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for value, c in report["per_value"].items():
        off = c["normal_flagged"] + c["anomalous_flagged"] - c["found_on_object"]
        rows.append(
            f"| {value} | {c['normal_flagged']}/{c['normal']} | "
            f"{c['anomalous_flagged']}/{c['anomalous']} | "
            f"{c['found_on_object']}/{c['anomalous']} | {off}/{c['normal'] + c['anomalous']} | "
            f"{c['anomaly_pixels_masked']}/{c['anomaly_pixels']} | "
            f"{c['detect_ms_median'] or 0:.1f} |"
        )
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rule", choices=sorted(RULES))
    parser.add_argument("sequences", nargs="+", metavar="SEQ", help="PATH or PATH:SPLIT")
    parser.add_argument("--values", default="0,1,2,4,8")
    parser.add_argument("--profile", default="default")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    values = [float(v) for v in args.values.split(",")]
    base = params_from(args.profile, [])
    report = {}
    for item in args.sequences:
        path, _, split = item.partition(":")
        report[item] = measure(args.rule, path, split or None, values, base)
        print(table(args.rule, item, report[item]), flush=True)
    out = args.out or Path(f"reports/sky_{args.rule}.json")
    return finish(out, {"rule": args.rule, "profile": args.profile, "sequences": report})


if __name__ == "__main__":
    sys.exit(main())
