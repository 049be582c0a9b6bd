"""The local cues per object kind: recall by type, by what lies behind, by size.

Runs named settings (as :mod:`benchmarks.stations_bench`: ``default``,
``default:local_weight=1``, ...) on the same frames, each reference rendered once, and
prints per setting the pooled P.AP, P.AUROC, P.FPR95 and I.AUROC, then the share of anomaly
pixels above the threshold where the setting's pooled false-positive rate is 5 %:

* per anomaly type;
* per kind of pixel: *dark* (query luma at most :data:`DARK_LUMA`) or not, over station
  (the reference, nearest-resized to the query, has a luma above :data:`SPACE_LUMA` there) or
  over space; and the dark pixels over space that are *black*, as dark as space (luma at
  most :data:`SPACE_LUMA`): an object as dark as space in front of space is invisible to any
  reference comparison, and its row says so by being near the rate of normal pixels (5 %);
* small objects (frames whose anomaly holds at most :data:`SMALL_PIXELS` pixels at the
  query's resolution) against the rest.

With ``--objects`` ROOT is an objects sequence (``allo-synth generate --preset objects``)
and it prints instead, per setting, the detection coverage of ``benchmarks.objects`` (object-
frames whose instance pixels the detection mask touches, and half covers, per placement) and
the share of frames without a showing object that the detector flags; detections are cached
under ``--cache`` per setting.

Frames are streamed (only the anomaly pixels' scores and every
:data:`NEGATIVE_STRIDE`-th normal pixel's are kept), so a 1080p split fits in memory;
``--limit N`` takes N evenly spaced frames.

Usage::

    python -m benchmarks.local_cues data/bench_val --sequence --split val \\
        --settings default,default:local_weight=1
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from allo_mrad_ros.detector import METHODS
from allo_mrad_ros.evaluation.objects import detection_coverage
from allo_mrad_ros.metrics import MetricsAccumulator, bootstrap_ap_difference, frame_counts
from allo_mrad_ros.pipeline import PipelineConfig
from allo_mrad_ros.render import ReferenceProvider, RenderSettings
from allo_mrad_ros.sequence import read_sequence
from allo_mrad_ros.view import View
from benchmarks.objects import detections
from benchmarks.stations import BENCH_SPLITS
from benchmarks.stations_bench import MASK_ANOMALY, parse_setting

DARK_LUMA = 40
"""A query pixel with a luma at most this (8-bit levels) is dark."""

SPACE_LUMA = 8
"""A reference pixel with a luma at most this is space."""

SMALL_PIXELS = 100
"""An anomaly of at most this many pixels (query resolution) is small."""

NEGATIVE_STRIDE = 64
"""Every this-many-th normal pixel is kept for the 5 % false-positive threshold."""


def _kinds(image: np.ndarray, reference: np.ndarray, positive: np.ndarray) -> np.ndarray:
    # 0 dark over station, 1 dark over space, 2 other over station, 3 other over space,
    # 4 as dark as space over space (also counted in 1).
    height, width = image.shape[:2]
    near = cv2.resize(reference, (width, height), interpolation=cv2.INTER_NEAREST)
    ref_luma = cv2.cvtColor(near, cv2.COLOR_RGB2GRAY)[positive]
    luma = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)[positive]
    return (luma > DARK_LUMA).astype(np.int8) * 2 + (ref_luma <= SPACE_LUMA), (
        luma <= SPACE_LUMA
    ) & (ref_luma <= SPACE_LUMA)


KIND_NAMES = (
    "dark over station",
    "dark over space",
    "other over station",
    "other over space",
    "black (as dark as space) over space",
)


def _sequences(root: Path, sequence: bool, split: str) -> list[tuple[str, Path, str | None]]:
    if sequence:
        return [(root.name, root, split)]
    return [(name, root / split / name, None) for name in BENCH_SPLITS[split]]


def objects_coverage(root: Path, split: str, settings: list, cache: Path, jobs: int) -> dict:
    """Per setting: detection coverage per placement and the normal frames flagged."""
    sequence = read_sequence(root, check_images=False)
    report = {}
    for s in settings:
        config = PipelineConfig(params=s.params, methods=("MRAD",))
        run = detections(root, cache, split, config, jobs)

        def instances(index: int) -> np.ndarray | None:
            return sequence.load_instances(sequence.frames[index])

        normal = [f for f in run.frames if not f.showing]
        report[s.name] = {
            "coverage": detection_coverage(run, instances),
            "normal_frames": len(normal),
            "normal_flagged": sum(f.frame_flagged for f in normal),
            "detect_ms_median": round(float(np.median([f.detect_ms for f in run.frames])), 2),
        }
        print(f"{s.name}: {json.dumps(report[s.name])}", flush=True)
    return report


def main(argv: list[str] | None = None) -> int:
    """Run the settings and print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", type=Path)
    parser.add_argument("--sequence", action="store_true", help="ROOT is one sequence")
    parser.add_argument("--split", choices=("train", "val", "test"), default="val")
    parser.add_argument("--settings", default="default,default:local_weight=1")
    parser.add_argument("--limit", type=int, default=0, help="N evenly spaced frames")
    parser.add_argument("--reference-scale", type=float, default=RenderSettings().reference_scale)
    parser.add_argument("--out", type=Path, help="JSON report")
    parser.add_argument(
        "--compare", default="", help="A,B: paired frame bootstrap of P.AP(B) - P.AP(A)"
    )
    parser.add_argument("--objects", action="store_true", help="ROOT is an objects sequence")
    parser.add_argument("--cache", type=Path, default=Path("data/local_cues_objects_cache"))
    parser.add_argument("--jobs", type=int, default=1)
    args = parser.parse_args(argv)
    settings = [parse_setting(text) for text in args.settings.split(",")]
    if args.objects:
        report = objects_coverage(args.root, args.split, settings, args.cache, args.jobs)
        if args.out is not None:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(json.dumps(report, indent=2))
        return 0
    pooled = {s.name: MetricsAccumulator() for s in settings}
    negatives: dict[str, list[np.ndarray]] = {s.name: [] for s in settings}
    positives: dict[str, list[np.ndarray]] = {s.name: [] for s in settings}
    labels: list[tuple[str, np.ndarray, bool]] = []
    times: dict[str, list[float]] = {s.name: [] for s in settings}
    tables: dict[str, list[np.ndarray]] = {s.name: [] for s in settings}
    for _station, folder, split in _sequences(args.root, args.sequence, args.split):
        seq = read_sequence(folder)
        frames = [f for f in seq.frames if split is None or f.split == split]
        if args.limit and args.limit < len(frames):
            frames = [frames[i] for i in np.linspace(0, len(frames) - 1, args.limit).astype(int)]
        provider = ReferenceProvider(
            seq.meta.mesh, seq.meta.camera, RenderSettings(args.reference_scale)
        )
        try:
            for frame in frames:
                image, truth = seq.load_image(frame), seq.load_mask(frame)
                reference = provider.render(View.of_frame(frame))
                positive = truth == MASK_ANOMALY
                kinds, black = _kinds(image, reference, positive)
                kinds = np.where(black, 4, kinds)
                small = 0 < np.count_nonzero(positive) <= SMALL_PIXELS
                labels.append((frame.anomaly or "?", kinds, small))
                for s in settings:
                    result = METHODS[s.method](image, reference, s.params)
                    times[s.name].append(result.timings_ms["total"])
                    score = result.score
                    pooled[s.name].update(score, result.image_score, truth)
                    tables[s.name].append(frame_counts(score, truth))
                    positives[s.name].append(score[positive])
                    # A copy: a view would keep the whole frame's map alive.
                    negatives[s.name].append(score[~positive][::NEGATIVE_STRIDE].copy())
        finally:
            provider.close()
    report: dict = {"frames": len(labels), "settings": {}}
    for s in settings:
        metrics = pooled[s.name].compute()
        threshold = float(np.quantile(np.concatenate(negatives[s.name]), 0.95))
        by_type: dict[str, list[int]] = {}
        by_kind = np.zeros((5, 2), np.int64)
        by_size = {"small": [0, 0], "larger": [0, 0]}
        for (anomaly, kinds, small), scores in zip(labels, positives[s.name], strict=True):
            if scores.size == 0:
                continue
            hit = scores > threshold
            counts = by_type.setdefault(anomaly, [0, 0])
            counts[0] += int(hit.sum())
            counts[1] += hit.size
            for kind in range(5):
                # The black pixels over space are dark over space too.
                chosen = (kinds == kind) | ((kinds == 4) & (kind == 1))
                by_kind[kind] += (int(hit[chosen].sum()), int(chosen.sum()))
            size = by_size["small" if small else "larger"]
            size[0] += int(hit.sum())
            size[1] += hit.size

        def share(hits: int, total: int) -> float | None:
            return round(100.0 * float(hits) / float(total), 1) if total else None

        report["settings"][s.name] = {
            "p_ap": round(100 * metrics.p_ap, 1),
            "p_auroc": round(100 * metrics.p_auroc, 1),
            "p_fpr95": round(100 * metrics.p_fpr95, 1),
            "i_auroc": round(100 * metrics.i_auroc, 1),
            "detect_ms_median": round(float(np.median(times[s.name])), 2),
            "recall_by_type": {k: share(*v) for k, v in sorted(by_type.items())},
            "recall_by_kind": {
                name: {"recall": share(*by_kind[i]), "pixels": int(by_kind[i][1])}
                for i, name in enumerate(KIND_NAMES)
            },
            "recall_by_size": {
                k: {"recall": share(*v), "pixels": v[1]} for k, v in by_size.items()
            },
        }
    a_name, _, b_name = args.compare.partition(",")
    if a_name in tables and b_name in tables:
        diffs = 100 * bootstrap_ap_difference(
            np.stack(tables[a_name]), np.stack(tables[b_name]), 1000
        )
        low, high = (round(float(v), 1) for v in np.percentile(diffs, [2.5, 97.5]))
        point = report["settings"][b_name]["p_ap"] - report["settings"][a_name]["p_ap"]
        report["compare"] = {"a": a_name, "b": b_name, "difference": round(point, 1)}
        report["compare"]["ci95"] = [low, high]
    print(f"{report['frames']} frames")
    for name, row in report["settings"].items():
        print(
            f"{name}: P.AP {row['p_ap']} P.AUROC {row['p_auroc']} P.FPR95 {row['p_fpr95']} "
            f"I.AUROC {row['i_auroc']} detect ms {row['detect_ms_median']}"
        )
        print(f"  recall at 5 % FPR by type: {row['recall_by_type']}")
        print(f"  by kind: {row['recall_by_kind']}")
        print(f"  by size: {row['recall_by_size']}")
    if "compare" in report:
        c = report["compare"]
        print(f"P.AP {c['b']} - {c['a']}: {c['difference']:+.1f} points, 95 % CI {c['ci95']}")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
