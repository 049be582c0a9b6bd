"""Photometric robustness: MRAD variants on queries perturbed as a camera differs from a render.

Every query of a sequence split is perturbed by each of
:data:`~harness.perturbations.PERTURBATIONS` (the reference stays the
clean render), and each detector variant is scored: the fraction of pixels its mask flags on
normal frames (mean and worst frame), its image-level AUROC and its pixel step AP. This is
the measurement behind docs/detector.md, "Photometric model".

    python -m benchmarks.photometric --sequence data/bench_val --split val
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from allo_mrad_ros.detector import METHODS, MradParams, profile
from allo_mrad_ros.metrics import MetricsAccumulator
from allo_mrad_ros.sequence import read_sequence
from allo_mrad_ros.view import View
from benchmarks.tradeoff import Sweep, split_frames
from benchmarks.tradeoff_settings import PREVIOUS_DEFAULT, render_settings
from harness.perturbations import PERTURBATIONS


def variants() -> dict[str, tuple[str, MradParams]]:
    """The compared detectors: name -> (method, parameters)."""
    base = profile("default")
    return {
        "previous default (no photometric model, tolerance growth)": (
            "MRAD",
            PREVIOUS_DEFAULT.replace(pixel_score="continuous"),
        ),
        "covariance floor 10 % of the variance (rel_floor 0.1)": (
            "MRAD",
            base.replace(photometric="none", rel_floor=0.1),
        ),
        "cell_affine, tolerance growth": (
            "MRAD",
            base.replace(growth="tolerance", noise_removal="cell_spread"),
        ),
        "cell_affine, hysteresis (default)": ("MRAD", base),
        "PAD": ("PAD", base),
    }


@dataclass
class Tally:
    """Per (variant, perturbation): metrics and the fraction flagged on normal frames."""

    metrics: MetricsAccumulator = field(default_factory=MetricsAccumulator)
    normal_flagged: list[float] = field(default_factory=list)

    def row(self) -> dict:
        """Summary figures as fractions."""
        m = self.metrics.compute()
        flagged = np.asarray(self.normal_flagged or [np.nan])
        return {
            "normal_flagged_mean": float(flagged.mean()),
            "normal_flagged_max": float(flagged.max()),
            "i_auroc": m.i_auroc,
            "p_ap": m.p_ap,
        }


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sequence", type=Path, default=Path("data/bench_val"))
    parser.add_argument("--split", default="val")
    parser.add_argument("--limit", type=int, default=40, help="frames (evenly spaced)")
    parser.add_argument("--reference-scale", type=float, default=0.125)
    parser.add_argument("--out", type=Path, default=Path("reports/photometric.json"))
    args = parser.parse_args(argv)
    sequence = read_sequence(args.sequence)
    frames = split_frames(sequence, args.split, args.limit)
    detectors = variants()
    perturbations = {"none": lambda im: im, **PERTURBATIONS}
    tallies = {(v, p): Tally() for v in detectors for p in perturbations}
    sweep = Sweep(sequence)
    provider = sweep.provider(render_settings(args.reference_scale))
    try:
        for frame in tqdm(frames, desc="photometric", unit="frame", leave=False):
            image, truth = sequence.load_image(frame), sequence.load_mask(frame)
            reference = provider.render(View.of_frame(frame))
            for p_name, perturb in perturbations.items():
                query = perturb(image)
                for v_name, (method, params) in detectors.items():
                    result = METHODS[method](query, reference, params)
                    tally = tallies[v_name, p_name]
                    tally.metrics.update(result.score, result.image_score, truth)
                    if not frame.is_anomalous:
                        tally.normal_flagged.append(result.area / result.mask.size)
    finally:
        sweep.close()
    rows = [{"variant": v, "perturbation": p, **t.row()} for (v, p), t in tallies.items()]
    print(
        f"{args.sequence} {args.split}: {len(frames)} frames "
        f"({sum(f.is_anomalous for f in frames)} anomalous); figures in %"
    )
    for v_name in detectors:
        print(f"\n{v_name}")
        print(f"{'perturbation':<22}{'normal flagged':>15}{'worst':>8}{'I.AUROC':>9}{'P.AP':>7}")
        for r in rows:
            if r["variant"] == v_name:
                print(
                    f"{r['perturbation']:<22}{100 * r['normal_flagged_mean']:>15.2f}"
                    f"{100 * r['normal_flagged_max']:>8.2f}{100 * r['i_auroc']:>9.1f}"
                    f"{100 * r['p_ap']:>7.1f}"
                )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"sequence": str(args.sequence), "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
