"""Image score: which frame score ranks anomalous frames best (I.AUROC), and how robustly.

For every frame of a sequence split, MRAD (the given profile) runs on the query and on the
query perturbed as a camera differs from a render (exposure, tone curve, gamma); each
candidate frame score is computed from the same result: the mask's area (the paper's
decision) and the mean of the top fraction of the pixel ranking map, for several fractions
(one pixel: the map's maximum, anomalib's image score). The map-based candidates are taken
on the full-resolution map (``detect`` takes them at the processing resolution: the same
fraction of an upsampled map, within interpolation). This is the measurement behind the
default ``image_score`` / ``image_top_fraction`` (docs/detector.md, "Parameters").

    python -m benchmarks.image_score --sequence data/bench_val --split val
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from allo_mrad_ros.detector import DetectionResult, MradParams, detect, profile
from allo_mrad_ros.detector.decision import image_score
from allo_mrad_ros.metrics import roc_auc
from allo_mrad_ros.sequence import read_sequence
from allo_mrad_ros.view import View
from benchmarks import finish
from benchmarks.tradeoff import Sweep, split_frames
from benchmarks.tradeoff_settings import render_settings
from harness.perturbations import PERTURBATIONS

FRACTIONS = (1e-3, 3e-4, 1e-4, 3e-5, 0.0)
"""Top fractions of the map compared (0: one pixel, the maximum)."""

PERTURBED = ("S tone curve", "exposure x0.6", "exposure x1.6", "gamma 0.8")


def candidates(result: DetectionResult, params: MradParams) -> dict[str, float]:
    """Every candidate frame score of one detection result."""
    scores = {"area": float(result.area)}
    for fraction in FRACTIONS:
        rule = params.replace(image_score="map_top", image_top_fraction=fraction or 1e-12)
        label = f"map top {fraction:g}" if fraction else "map maximum"
        scores[label] = image_score(result.score, result.area, rule)
    return scores


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sequence", type=Path, default=Path("data/bench_val"))
    parser.add_argument("--split", default="val")
    parser.add_argument("--limit", type=int, default=None, help="frames (evenly spaced)")
    parser.add_argument("--profile", default="default")
    parser.add_argument("--reference-scale", type=float, default=0.125)
    parser.add_argument("--out", type=Path, default=Path("reports/image_score.json"))
    args = parser.parse_args(argv)
    sequence = read_sequence(args.sequence)
    frames = split_frames(sequence, args.split, args.limit)
    params = profile(args.profile)
    perturbations = {"none": lambda image: image, **{p: PERTURBATIONS[p] for p in PERTURBED}}
    scores: dict[str, list[dict[str, float]]] = {p: [] for p in perturbations}
    sweep = Sweep(sequence)
    provider = sweep.provider(render_settings(args.reference_scale))
    try:
        for frame in tqdm(frames, desc="image score", unit="frame", leave=False):
            image = sequence.load_image(frame)
            reference = provider.render(View.of_frame(frame))
            for name, perturb in perturbations.items():
                scores[name].append(candidates(detect(perturb(image), reference, params), params))
    finally:
        sweep.close()
    labels = np.array([frame.is_anomalous for frame in frames])
    table = {
        candidate: {
            name: roc_auc(np.array([row[candidate] for row in rows], dtype=float), labels)
            for name, rows in scores.items()
        }
        for candidate in scores["none"][0]
    }
    print(
        f"{args.sequence} {args.split}: {len(frames)} frames ({labels.sum()} anomalous); "
        f"I.AUROC in % of each candidate frame score, query as rendered and perturbed"
    )
    print(f"{'candidate':<18}" + "".join(f"{name[:13]:>15}" for name in perturbations))
    for candidate, row in table.items():
        print(f"{candidate:<18}" + "".join(f"{100 * row[name]:>15.2f}" for name in perturbations))
    return finish(
        args.out,
        {
            "sequence": str(args.sequence),
            "split": args.split,
            "frames": len(frames),
            "profile": args.profile,
            "i_auroc": table,
        },
    )


if __name__ == "__main__":
    sys.exit(main())
