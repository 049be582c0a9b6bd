"""Build the table that calibrates a region's score: the peaks of regions found on normal frames.

Generates nothing itself: run it on a validation sequence made with

    allo-synth generate --preset bench-val --seed 4242 --frames 640 --width 640 --height 360 \\
        --out data/region-calibration --overwrite

It runs MRAD with the default parameters (reference rendered from each frame's pose with the
sequence's own station model) on every frame without anomaly pixels and collects the peak
evidence (``Region.peak_score``, 0..255) of every region the detector grows there. When the
normal frames give fewer than ``--min-regions`` regions, it also collects the regions of the
anomalous frames whose bounding box holds no anomaly pixel of the truth mask (still evidence
from normal pixels), and the table's header says so. The sorted peaks and a header saying how
they were made are written to ``allo_mrad_ros/data/region_peaks_normal.json``, which
:func:`allo_mrad_ros.detector.regions.region_score` reads.

Usage: ``python -m benchmarks.region_calibration data/region-calibration``
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from allo_mrad_ros.evaluation.sources import open_sequence
from allo_mrad_ros.pipeline import Pipeline, PipelineConfig
from allo_mrad_ros.render import ReferenceProvider

TABLE = (
    Path(__file__).resolve().parent.parent / "allo_mrad_ros" / "data" / "region_peaks_normal.json"
)
GENERATE = (
    "allo-synth generate --preset bench-val --seed 4242 --frames 640 --width 640 --height 360 "
    "--out data/region-calibration --overwrite"
)
COMMAND = "python -m benchmarks.region_calibration data/region-calibration"
MIN_REGIONS = 50
ANOMALY = 2


def collect(root: Path, *, min_regions: int = MIN_REGIONS) -> dict:
    """The peaks of MRAD's regions on the normal evidence of the sequence at ``root``.

    Returns
    -------
    dict
        The table's header fields and ``peaks``, sorted ascending.
    """
    source = open_sequence(root)
    config = PipelineConfig(methods=("MRAD",))
    pipeline = Pipeline(ReferenceProvider(source.mesh, source.camera, config.render), config)
    normal: list[float] = []
    outside: list[float] = []
    frames = {"normal": 0, "anomalous": 0}
    try:
        for frame in source.frames(source.select(None)):
            result = pipeline.process(frame.image, frame.view).primary
            if not frame.is_anomalous:
                frames["normal"] += 1
                normal.extend(region.peak_score for region in result.regions)
                continue
            frames["anomalous"] += 1
            truth = frame.mask == ANOMALY
            for region in result.regions:
                x, y, w, h = region.box
                if not truth[y : y + h, x : x + w].any():
                    outside.append(region.peak_score)
    finally:
        pipeline.provider.close()
    peaks = list(normal)
    sources = f"every region on the {frames['normal']} normal frames ({len(normal)} regions)"
    if len(normal) < min_regions:
        peaks += outside
        sources += (
            f", and, as the normal frames gave fewer than {min_regions}, the {len(outside)} "
            f"regions of the {frames['anomalous']} anomalous frames whose box holds no anomaly "
            "pixel of the truth mask"
        )
    values = sorted(float(p) for p in peaks)
    if not values or not all(math.isfinite(v) for v in values):
        raise SystemExit(f"{root}: no finite region peaks to calibrate with ({len(values)})")
    return {
        "description": (
            "Sorted peak evidence (Region.peak_score, 0..255) of the regions MRAD with the "
            "default parameters (MradParams()) grows on normal evidence of a validation "
            "sequence: " + sources + ". A region's score is the fraction of these peaks below "
            "its own (ties count half)."
        ),
        "command": COMMAND,
        "sequence_command": GENERATE,
        "sequence": source.name,
        "frames": frames,
        "regions_normal_frames": len(normal),
        "regions_outside_truth": len(outside) if len(normal) < min_regions else 0,
        "count": len(values),
        "peaks": values,
    }


def main(argv: list[str] | None = None) -> int:
    """Collect the peaks, write the table and print its summary."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--min-regions", type=int, default=MIN_REGIONS)
    parser.add_argument("--out", type=Path, default=TABLE)
    args = parser.parse_args(argv)
    if not TABLE.exists():
        # The detector reads the table to score every region; the peaks collected here do
        # not depend on the scores, so a first build starts from a one-peak stand-in.
        TABLE.write_text(json.dumps({"peaks": [0.0]}) + "\n", encoding="utf-8")
    table = collect(args.sequence, min_regions=args.min_regions)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(table, indent=1) + "\n", encoding="utf-8")
    peaks = np.asarray(table["peaks"])
    quantiles = np.percentile(peaks, [10, 50, 90])
    print(table["description"])
    print(
        f"{table['count']} peaks, min {peaks[0]:.1f}, p10 {quantiles[0]:.1f}, median "
        f"{quantiles[1]:.1f}, p90 {quantiles[2]:.1f}, max {peaks[-1]:.1f}; wrote {args.out}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
