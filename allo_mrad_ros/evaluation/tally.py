"""Per-frame outcomes and their totals: pixel counts per score, image scores, decisions, latencies.

Workers send a :class:`FrameOutcome` per frame (counts per distinct score, not the score
maps); the parent adds them into one :class:`Tally` per method and group. Counts add up,
so the totals equal a single :class:`~allo_mrad_ros.metrics.MetricsAccumulator` fed every
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
    PooledScoreCounts,
    ScoreCounts,
)

NORMAL_GROUP = "normal"


# ----------------------------------------------------------------- per-frame outcome
@dataclass
class MethodOutcome:
    """One method on one frame: pixel counts, image score and decision, timings."""

    counts: ScoreCounts
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


def frame_counts(score: np.ndarray, mask: np.ndarray) -> ScoreCounts:
    """Per-frame pixel counts per distinct score, as :class:`MetricsAccumulator` pools them."""
    return ScoreCounts.of_frame(score, mask)


# ----------------------------------------------------------------- parent side
@dataclass
class Tally:
    """Accumulated counts of one method over one group of frames."""

    pixels: PooledScoreCounts = field(default_factory=PooledScoreCounts)
    image_scores: list[float] = field(default_factory=list)
    image_labels: list[bool] = field(default_factory=list)
    decisions: list[bool] = field(default_factory=list)

    def add(self, outcome: MethodOutcome, truth: bool) -> None:
        """Add one frame."""
        self.pixels.add(outcome.counts)
        self.image_scores.append(outcome.image_score)
        self.image_labels.append(truth)
        self.decisions.append(outcome.anomalous)


def merged_accumulator(tallies: Sequence[Tally]) -> MetricsAccumulator:
    """A :class:`MetricsAccumulator` holding the frames of all ``tallies``."""
    accumulator = MetricsAccumulator()
    for tally in tallies:
        accumulator.pixels.add_pool(tally.pixels)
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
