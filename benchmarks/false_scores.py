"""Where do pixels that are not anomalous score as anomalies? Per method, by kind of pixel.

Runs the evaluator's pipeline (reference rendered from the frame's pose) over a split and
sorts every pixel that is not an anomaly into one kind: within 2 px of the silhouette of
station and objects (``edge``), ``space``, or station pixels whose reference grey level is
``dark`` (< 40), ``mid`` or ``bright`` (>= 170). Per method and kind it reports the share
flagged by the mask and the share ranking above the median anomaly pixel of the ranking map
(the pixels that cost P.AP), and per sequence the median query-minus-reference grey level
on the station. For comparing a path-traced sequence with its rasterised twin.

Usage: ``python -m benchmarks.false_scores data/bench_cycles``
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from allo_mrad_ros.evaluation.sources import open_sequence
from allo_mrad_ros.pipeline import Pipeline, PipelineConfig
from allo_mrad_ros.render import ReferenceProvider
from benchmarks import finish

KINDS = ("edge", "space", "dark", "mid", "bright")
DARK, BRIGHT = 40.0, 170.0
EDGE_PX = 2


def pixel_kinds(mask: np.ndarray, reference_grey: np.ndarray) -> dict[str, np.ndarray]:
    """Disjoint boolean images of each kind; together they cover every non-anomaly pixel."""
    solid = (mask > 0).astype(np.uint8)
    size = 2 * EDGE_PX + 1
    kernel = np.ones((size, size), np.uint8)
    edge = (cv2.dilate(solid, kernel) != cv2.erode(solid, kernel)) & (mask != 2)
    station = (mask == 1) & ~edge
    return {
        "edge": edge,
        "space": (mask == 0) & ~edge,
        "dark": station & (reference_grey < DARK),
        "mid": station & (reference_grey >= DARK) & (reference_grey < BRIGHT),
        "bright": station & (reference_grey >= BRIGHT),
    }


def probe(root: Path, split: str = "test", limit: int | None = None) -> dict:
    """The shares per method and kind over ``split`` of the sequence at ``root``."""
    source = open_sequence(root)
    config = PipelineConfig(methods=("MRAD", "PAD", "RXD"))
    pipeline = Pipeline(ReferenceProvider(source.mesh, source.camera, config.render), config)
    flagged = {m: dict.fromkeys(KINDS, 0) for m in config.methods}
    scores: dict[str, dict[str, list]] = {
        m: {k: [] for k in (*KINDS, "anomaly")} for m in config.methods
    }
    totals = dict.fromkeys(KINDS, 0)
    offsets = []
    try:
        for frame in source.frames(source.select(split, limit)):
            processed = pipeline.process(frame.image, frame.view)
            height, width = frame.mask.shape
            reference = cv2.resize(processed.reference, (width, height))
            grey = reference.astype(np.float32).mean(axis=2)
            kinds = pixel_kinds(frame.mask, grey)
            station = kinds["dark"] | kinds["mid"] | kinds["bright"]
            if station.any():
                query_grey = frame.image.astype(np.float32).mean(axis=2)
                offsets.append(float(np.median(query_grey[station] - grey[station])))
            for kind, where in kinds.items():
                totals[kind] += int(np.count_nonzero(where))
            for name, result in processed.results.items():
                score = cv2.resize(result.score.astype(np.float32), (width, height))
                scores[name]["anomaly"].append(score[frame.mask == 2])
                for kind, where in kinds.items():
                    flagged[name][kind] += int(np.count_nonzero((result.mask > 0) & where))
                    scores[name][kind].append(score[where])
    finally:
        pipeline.provider.close()
    methods = {}
    for name in config.methods:
        anomaly = np.concatenate(scores[name]["anomaly"])
        median = float(np.median(anomaly)) if anomaly.size else None
        above = {}
        for kind in KINDS:
            values = np.concatenate(scores[name][kind])
            above[kind] = (
                None if median is None or not values.size else float(np.mean(values > median))
            )
        methods[name] = {
            "median_anomaly_score": median,
            "flagged": {k: flagged[name][k] / totals[k] if totals[k] else None for k in KINDS},
            "above_median_anomaly": above,
        }
    return {
        "sequence": str(root),
        "frames": len(offsets),
        "pixels": totals,
        "median_query_minus_reference_grey": float(np.median(offsets)) if offsets else None,
        "methods": methods,
    }


def _percent(share: float | None) -> str:
    return "-" if share is None else f"{100 * share:.2f} %"


def main(argv: list[str] | None = None) -> int:
    """Print the shares per method and kind; write the JSON report."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("sequence", type=Path)
    parser.add_argument("--split", default="test")
    parser.add_argument("--limit", type=int, help="at most this many frames")
    parser.add_argument("--out", type=Path, default=Path("reports/false_scores.json"))
    args = parser.parse_args(argv)
    report = probe(args.sequence, args.split, args.limit)
    print(
        f"{report['sequence']}: {report['frames']} frames; station grey, query - reference: "
        f"{report['median_query_minus_reference_grey']:+.1f} DN (median of frame medians)"
    )
    print("method | measure | " + " | ".join(f"{k} ({report['pixels'][k]} px)" for k in KINDS))
    for name, row in report["methods"].items():
        for measure in ("flagged", "above_median_anomaly"):
            shares = " | ".join(_percent(row[measure][k]) for k in KINDS)
            print(f"{name} | {measure} | {shares}")
    return finish(args.out, report)


if __name__ == "__main__":
    raise SystemExit(main())
