"""Pixel-metric accumulation: time per frame and memory, exact counts against the old binning.

Synthetic score maps shaped like the detector's (a map at a quarter of the resolution, 70 %
of it in patches tied at 1.0 and the rest spread, upscaled bilinearly to 1080p: about 60 %
of the pixels at 1.0 and some 0.7 M distinct values a frame; a few anomalous discs scoring
higher) are fed to :class:`~allo_mrad_ros.metrics.MetricsAccumulator`. Each frame is also
added to the 1/64-unit histogram the metrics were read from before, in the same loop, so
the two per-frame times are measured side by side, as CPU time of this process (so other
processes on a shared machine do not count). A second pass under ``tracemalloc`` gives the
accumulator's peak memory over the whole run (the score maps themselves are made outside
what is counted: the peak is the largest of the pooled counts held before a frame plus
what that frame's update and the final computation allocate at their height).

    python -m benchmarks.metrics_update --frames 100
"""

from __future__ import annotations

import argparse
import time
import tracemalloc
from collections.abc import Iterator
from itertools import islice
from pathlib import Path

import cv2
import numpy as np

from allo_mrad_ros.metrics import DEFAULT_MAX_ENTRIES, POSITIVE_CLASS, MetricsAccumulator
from benchmarks import finish, machine_facts

OLD_BINS_PER_UNIT = 64
"""The histogram the pixel metrics were read from before: 1/64 of a unit on 0..255."""


def synthetic_frame(
    rng: np.random.Generator, size: tuple[int, int] = (1920, 1080)
) -> tuple[np.ndarray, np.ndarray]:
    """One score map (float32, 0..255) and its mask (2: anomaly, 1: station, 0: space)."""
    width, height = size
    small = (max(8, width // 4), max(8, height // 4))
    # Plateaus in patches, as a detector's floor is: a smoothed random field's lowest 70 %.
    field = cv2.GaussianBlur(rng.random((small[1], small[0])).astype(np.float32), (0, 0), 3)
    work = np.where(
        field < np.quantile(field, 0.7),
        np.float32(1.0),
        rng.gamma(1.5, 6.0, (small[1], small[0])).astype(np.float32),
    )
    truth = rng.integers(0, 2, (small[1], small[0]), dtype=np.uint8)
    for _ in range(int(rng.integers(0, 4))):
        centre = (int(rng.integers(0, small[0])), int(rng.integers(0, small[1])))
        radius = int(rng.integers(2, max(3, small[1] // 10)))
        disc = np.zeros_like(truth)
        cv2.circle(disc, centre, radius, 1, -1)
        work[disc > 0] += rng.gamma(2.0, 15.0, int(disc.sum())).astype(np.float32)
        truth[disc > 0] = POSITIVE_CLASS
    score = cv2.resize(np.clip(work, 0, 255), size, interpolation=cv2.INTER_LINEAR)
    mask = cv2.resize(truth, size, interpolation=cv2.INTER_NEAREST)
    return score, mask


def binned_update(
    positives: np.ndarray, negatives: np.ndarray, score: np.ndarray, mask: np.ndarray
) -> None:
    """The previous accumulation: round to 1/64 of a unit and add per-bin counts."""
    if not np.isfinite(score).all():
        raise ValueError("score map contains NaN or Inf")
    index = np.rint(np.clip(score, 0.0, 255.0) * OLD_BINS_PER_UNIT).astype(np.int64).ravel()
    positive = (mask == POSITIVE_CLASS).ravel()
    positives += np.bincount(index[positive], minlength=positives.size)
    negatives += np.bincount(index[~positive], minlength=negatives.size)


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--width", type=int, default=1920)
    parser.add_argument("--height", type=int, default=1080)
    parser.add_argument("--max-entries", type=int, default=DEFAULT_MAX_ENTRIES)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("reports/metrics_update.json"))
    args = parser.parse_args(argv)
    size = (args.width, args.height)

    def frames() -> Iterator[tuple[np.ndarray, np.ndarray]]:
        rng = np.random.default_rng(args.seed)
        for _ in range(args.frames):
            yield synthetic_frame(rng, size)

    distinct = [int(np.unique(score).size) for score, _ in islice(frames(), 3)]
    print(
        f"{args.frames} frames {args.width}x{args.height}, distinct scores per frame "
        f"(first 3): {distinct}"
    )

    # Time: both accumulations of every frame in one loop, alternating which goes first.
    accumulator = MetricsAccumulator(max_entries=args.max_entries)
    bins = round(255 * OLD_BINS_PER_UNIT) + 1
    positives, negatives = np.zeros(bins, np.int64), np.zeros(bins, np.int64)
    exact_ms, binned_ms = [], []
    for index, (score, mask) in enumerate(frames()):
        order = ("exact", "binned") if index % 2 == 0 else ("binned", "exact")
        for which in order:
            start = time.process_time()
            if which == "exact":
                accumulator.update(score, 0.0, mask)
                exact_ms.append(1e3 * (time.process_time() - start))
            else:
                binned_update(positives, negatives, score, mask)
                binned_ms.append(1e3 * (time.process_time() - start))
    start = time.process_time()
    metrics = accumulator.compute()
    compute_s = time.process_time() - start

    # Memory: the accumulator alone, over the whole run and its final computation.
    traced = MetricsAccumulator(max_entries=args.max_entries)
    tracemalloc.start()
    peak_bytes = 0
    for score, mask in frames():
        held = traced.pixels.nbytes
        tracemalloc.reset_peak()
        before = tracemalloc.get_traced_memory()[0]
        traced.update(score, 0.0, mask)
        peak_bytes = max(peak_bytes, held + tracemalloc.get_traced_memory()[1] - before)
    held = traced.pixels.nbytes
    tracemalloc.reset_peak()
    before = tracemalloc.get_traced_memory()[0]
    traced.compute()
    peak_bytes = max(peak_bytes, held + tracemalloc.get_traced_memory()[1] - before)
    tracemalloc.stop()

    table = traced.pixels.table()
    report = {
        "frames": args.frames,
        "size": [args.width, args.height],
        "max_entries": args.max_entries,
        "update_ms": {
            "exact": {"median": float(np.median(exact_ms)), "mean": float(np.mean(exact_ms))},
            "binned_before": {
                "median": float(np.median(binned_ms)),
                "mean": float(np.mean(binned_ms)),
            },
        },
        "compute_s": compute_s,
        "peak_bytes": peak_bytes,
        "pooled_entries": table.size,
        "pooled_bytes": table.nbytes,
        "exact": metrics.exact,
        "metrics": metrics.as_dict(),
        "error_bounds": metrics.error_bounds,
        "machine": machine_facts(),
    }
    print(
        f"per-frame update, ms (median / mean): exact {report['update_ms']['exact']['median']:.1f}"
        f" / {report['update_ms']['exact']['mean']:.1f}, 1/64 histogram (before) "
        f"{report['update_ms']['binned_before']['median']:.1f}"
        f" / {report['update_ms']['binned_before']['mean']:.1f}; compute {compute_s:.2f} s"
    )
    print(
        f"accumulator peak {peak_bytes / 2**20:.1f} MiB ({peak_bytes} bytes), pooled table "
        f"{table.size} entries ({table.nbytes / 2**20:.1f} MiB); exact: {metrics.exact}"
    )
    print("metrics:", {k: round(v, 6) for k, v in metrics.as_dict().items()})
    print("error bounds:", {k: float(f"{v:.2g}") for k, v in metrics.error_bounds.items()})
    return finish(args.out, report)


if __name__ == "__main__":
    raise SystemExit(main())
