"""Measure the detector parameters docs/method.md leaves to measurement on varied synthetic scenes.

Scenes come from :mod:`allo_mrad_ros.example_scene`: a blanket of random size pasted at a
random place (over sky or over structure) in half of the frames, sensor noise, a 2-pixel
shift, the reference at 1/4 resolution. Prints P.AP, P.AUROC, I.AUROC and P.FPR95 per
variant. It decides nothing by itself; docs/detector.md records what was chosen from it, and
the ALLO-like validation split (``make bench``) supersedes it.

Usage: ``python -m benchmarks.param_study [--scenes 16] [--out FILE]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from allo_mrad_ros.detector import METHODS, MradParams
from allo_mrad_ros.example_scene import camera_effects, paste_object, station_view
from allo_mrad_ros.metrics import MetricsAccumulator
from benchmarks import finish

VARIANTS: dict[str, dict] = {
    "default": {},
    "per_image scaling": {"score_scaling": "per_image"},
    "score_ref 250": {"score_ref": 250.0},
    "score_ref 4000": {"score_ref": 4000.0},
    "min_score 10": {"min_score": 10.0},
    "min_score 50": {"min_score": 50.0},
    "std_thresh 8": {"std_thresh": 8.0},
    "std_thresh 13": {"std_thresh": 13.0},
    "cell_spread": {"noise_removal": "cell_spread"},
    "no noise removal": {"noise_removal": "none"},
    "abs_floor 4": {"abs_floor": 4.0},
    "abs_floor 64": {"abs_floor": 64.0},
    "rel_floor 1e-2": {"rel_floor": 1e-2},
}


def make_scenes(
    count: int, height: int, width: int
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(query, reference, 3-class mask) triples; odd scenes carry an object."""
    scenes = []
    for index in range(count):
        rng = np.random.default_rng(1000 + index)
        reference = station_view(height, width, seed=index)
        station = np.any(reference > 0, axis=-1)
        mask = np.where(station, 1, 0).astype(np.uint8)
        image = reference
        if index % 2:
            centre = (rng.uniform(0.15, 0.85), rng.uniform(0.1, 0.9))
            image, object_mask = paste_object(reference, index, centre, rng.uniform(0.03, 0.12))
            mask[object_mask > 0] = 2
        query = camera_effects(image, noise_sd=rng.uniform(1.0, 3.0), shift_px=2, seed=index)
        mask = np.roll(mask, (2, 2), axis=(0, 1))
        small = cv2.resize(reference, (width // 4, height // 4), interpolation=cv2.INTER_AREA)
        scenes.append((query, small, mask))
    return scenes


def evaluate(method: str, params: MradParams, scenes: list) -> dict[str, float]:
    """The four metrics of one method and parameter set over the scenes."""
    accumulator = MetricsAccumulator()
    for query, reference, mask in scenes:
        result = METHODS[method](query, reference, params)
        accumulator.update(result.score, result.image_score, mask)
    return accumulator.compute().as_dict()


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenes", type=int, default=16)
    parser.add_argument("--height", type=int, default=540)
    parser.add_argument("--width", type=int, default=960)
    parser.add_argument("--out", type=Path, default=Path("reports/param_study.json"))
    args = parser.parse_args(argv)
    scenes = make_scenes(args.scenes, args.height, args.width)
    rows = {}
    print(f"{args.scenes} scenes at {args.width}x{args.height}, half with an object")
    print(f"{'variant':<22}{'P.AP':>8}{'P.AUROC':>9}{'I.AUROC':>9}{'P.FPR95':>9}")
    base = MradParams()
    entries = [(name, "MRAD", base.replace(**changes)) for name, changes in VARIANTS.items()]
    entries += [("PAD baseline", "PAD", base), ("RXD baseline", "RXD", base)]
    for name, method, params in entries:
        metrics = evaluate(method, params, scenes)
        rows[name] = metrics
        print(
            f"{name:<22}{metrics['p_ap']:>8.3f}{metrics['p_auroc']:>9.3f}"
            f"{metrics['i_auroc']:>9.3f}{metrics['p_fpr95']:>9.3f}"
        )
    return finish(args.out, rows)


if __name__ == "__main__":
    sys.exit(main())
