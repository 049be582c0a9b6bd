"""Per-frame outcomes and their totals: sparse pixel histograms, image scores, decisions, latencies.

Workers send a :class:`FrameOutcome` per frame (counts only, so little travels between
processes); the parent adds them into one :class:`Tally` per method and group. Histograms add
up, so the totals equal a single :class:`~allo_mrad_ros.metrics.MetricsAccumulator` fed every
frame."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from allo_mrad_ros.detector import DetectionResult
from allo_mrad_ros.localisation import ObjectOverlap, object_overlap
from allo_mrad_ros.metrics import (
    POSITIVE_CLASS,
    MetricsAccumulator,
    PixelScoreHistogram,
)

NORMAL_GROUP = "normal"


# ----------------------------------------------------------------- per-frame outcome
@dataclass
class SparseCounts:
    """Non-zero bins of a :class:`PixelScoreHistogram` (positives and negatives)."""

    bins: np.ndarray
    positives: np.ndarray
    negatives: np.ndarray

    @classmethod
    def of(cls, histogram: PixelScoreHistogram) -> SparseCounts:
        """Compress a histogram to its non-empty bins."""
        bins = np.flatnonzero(histogram.positives + histogram.negatives)
        return cls(bins, histogram.positives[bins], histogram.negatives[bins])

    def add_to(self, histogram: PixelScoreHistogram) -> None:
        """Add these counts into ``histogram``."""
        histogram.positives[self.bins] += self.positives
        histogram.negatives[self.bins] += self.negatives


@dataclass
class MethodOutcome:
    """One method on one frame: pixel counts, image score and decision, timings."""

    counts: SparseCounts
    image_score: float
    anomalous: bool
    timings_ms: dict[str, float]
    overlap: ObjectOverlap | None = None

    @classmethod
    def of(
        cls, result: DetectionResult, truth: np.ndarray, timings_ms: dict[str, float]
    ) -> MethodOutcome:
        """The outcome of one detection against the frame's ground truth."""
        has_object = bool(np.any(truth == POSITIVE_CLASS))
        return cls(
            frame_counts(result.score, truth),
            float(result.image_score),
            bool(result.anomalous),
            timings_ms,
            object_overlap(result.mask, truth) if has_object else None,
        )


@dataclass
class Overlay:
    """Small images of one frame for the overlay grid."""

    image: np.ndarray
    truth: np.ndarray
    masks: dict[str, np.ndarray]
    scores: dict[str, np.ndarray]


@dataclass
class FrameOutcome:
    """Everything the report needs from one frame."""

    index: int
    name: str
    anomaly: str
    truth_anomalous: bool
    methods: dict[str, MethodOutcome]
    timings_ms: dict[str, float]
    overlay: Overlay | None = None

    @property
    def group(self) -> str:
        """Anomaly type, or ``normal``."""
        return self.anomaly if self.truth_anomalous else NORMAL_GROUP


def frame_counts(score: np.ndarray, mask: np.ndarray) -> SparseCounts:
    """Per-frame pixel histogram, as :class:`MetricsAccumulator` would pool it."""
    histogram = PixelScoreHistogram()
    histogram.update(score, mask)
    return SparseCounts.of(histogram)


# ----------------------------------------------------------------- parent side
@dataclass
class Tally:
    """Accumulated counts of one method over one group of frames."""

    histogram: PixelScoreHistogram = field(default_factory=PixelScoreHistogram)
    image_scores: list[float] = field(default_factory=list)
    image_labels: list[bool] = field(default_factory=list)
    decisions: list[bool] = field(default_factory=list)

    def add(self, outcome: MethodOutcome, truth: bool) -> None:
        """Add one frame."""
        outcome.counts.add_to(self.histogram)
        self.image_scores.append(outcome.image_score)
        self.image_labels.append(truth)
        self.decisions.append(outcome.anomalous)


def merged_accumulator(tallies: Sequence[Tally]) -> MetricsAccumulator:
    """A :class:`MetricsAccumulator` holding the frames of all ``tallies``."""
    accumulator = MetricsAccumulator()
    for tally in tallies:
        accumulator.pixels.positives += tally.histogram.positives
        accumulator.pixels.negatives += tally.histogram.negatives
        accumulator.image_scores.extend(tally.image_scores)
        accumulator.image_labels.extend(tally.image_labels)
    return accumulator


def confusion(tallies: Sequence[Tally]) -> dict[str, int]:
    """Image-level decisions against the truth: tp, fp, tn, fn."""
    counts = {"tp": 0, "fp": 0, "tn": 0, "fn": 0}
    for tally in tallies:
        for truth, decision in zip(tally.image_labels, tally.decisions, strict=True):
            key = ("t" if truth == decision else "f") + ("p" if decision else "n")
            counts[key] += 1
    return counts


def latency_stats(samples: dict[str, list[float]]) -> dict[str, dict[str, float]]:
    """Median, 95th percentile and mean per stage, milliseconds."""
    stats = {}
    for stage, values in samples.items():
        array = np.asarray(values, dtype=np.float64)
        stats[stage] = {
            "median": float(np.median(array)),
            "p95": float(np.percentile(array, 95)),
            "mean": float(array.mean()),
            "count": int(array.size),
        }
    return stats
