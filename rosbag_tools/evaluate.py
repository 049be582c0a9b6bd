"""``allo-bag evaluate``: MRAD, PAD and RXD on every frame of a split, offline.

Every frame goes through :meth:`allo_mrad_ros.processing.FrameProcessor.process`, the step
the detector node runs: the reference is rendered at the frame's pose with the input's own
station model, then each method detects. Pixel scores are pooled into per-frame histograms
in the workers (exactly what :class:`~allo_mrad_ros.metrics.MetricsAccumulator` would add),
so only counts travel between processes; histograms add up, so the totals equal a single
accumulator fed every frame.

Per anomaly type, the metrics use that type's anomalous frames together with all normal
frames (the usual per-category reading).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from os import PathLike
from typing import Any

import cv2
import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector import METHODS, MradParams
from allo_mrad_ros.localisation import ObjectOverlap, object_overlap, summarise
from allo_mrad_ros.metrics import (
    POSITIVE_CLASS,
    AlloMetrics,
    Curve,
    MetricsAccumulator,
    PixelScoreHistogram,
)
from allo_mrad_ros.processing import FrameProcessor
from allo_mrad_ros.render import DEFAULT_SCALE, DEFAULT_SHADOWS, ReferenceRenderer
from rosbag_tools.frames import EvalFrame, FrameSource, open_source
from rosbag_tools.parallel import RunClock, run_frames

ALL_METHODS = ("MRAD", "PAD", "RXD")
NORMAL_GROUP = "normal"
OVERLAY_WIDTH = 320
OVERLAYS_PER_GROUP = 2


class EvaluationError(RuntimeError):
    """Evaluation cannot run (bad option) or a frame failed (the message names it)."""


@dataclass(frozen=True)
class EvaluationConfig:
    """Options of :func:`evaluate`.

    Parameters
    ----------
    methods : tuple of str
        Detectors, names from :data:`allo_mrad_ros.detector.METHODS`.
    params : MradParams
        Detector parameters (PAD and RXD use the shared post-processing ones).
    ref_scale : float
        Linear scale of the rendered reference, (0, 1].
    shadows : bool
        Render Sun shadows in the reference.
    split : str or None
        Split to evaluate; None means ``test`` if present, else every frame.
    limit : int or None
        Evaluate at most this many frames, evenly spread over the split.
    jobs : int
        Worker processes.
    overlays : int
        Example frames in the overlay grid (0: none).
    progress : bool
        Show a progress bar.
    """

    methods: tuple[str, ...] = ALL_METHODS
    params: MradParams = field(default_factory=MradParams)
    ref_scale: float = DEFAULT_SCALE
    shadows: bool = DEFAULT_SHADOWS
    split: str | None = None
    limit: int | None = None
    jobs: int = 1
    overlays: int = 8
    progress: bool = True

    def __post_init__(self) -> None:
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown or not self.methods:
            raise EvaluationError(f"unknown method(s) {unknown}; choose from {sorted(METHODS)}")
        if not (math.isfinite(self.ref_scale) and 0 < self.ref_scale <= 1):
            raise EvaluationError(f"ref_scale must be in (0, 1], got {self.ref_scale!r}")
        if self.jobs < 1:
            raise EvaluationError(f"jobs must be at least 1, got {self.jobs}")
        if self.limit is not None and self.limit < 1:
            raise EvaluationError(f"limit must be at least 1, got {self.limit}")
        if self.overlays < 0:
            raise EvaluationError(f"overlays must be >= 0, got {self.overlays}")


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
    area: float
    anomalous: bool
    timings_ms: dict[str, float]
    overlap: ObjectOverlap | None = None


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


# ----------------------------------------------------------------- worker side
@dataclass(frozen=True)
class RendererSetup:
    """What a worker needs to build its renderer and processor."""

    mesh: Any
    camera: CameraIntrinsics
    ref_scale: float
    shadows: bool


_STATE: dict[str, Any] = {}


def build_renderer(setup: RendererSetup) -> ReferenceRenderer:
    """The reference renderer of a run (one per process)."""
    return ReferenceRenderer(setup.mesh, setup.camera, scale=setup.ref_scale, shadows=setup.shadows)


def _init_evaluation(setup: RendererSetup, params: MradParams, methods: tuple[str, ...]) -> None:
    release_worker_state()
    renderer = build_renderer(setup)
    _STATE["renderer"] = renderer
    _STATE["processor"] = FrameProcessor(renderer, params, methods)


def release_worker_state() -> None:
    """Close this process's renderer (after an in-process run)."""
    renderer = _STATE.pop("renderer", None)
    _STATE.clear()
    if renderer is not None:
        renderer.close()


def _small(array: np.ndarray, interpolation: int) -> np.ndarray:
    height, width = array.shape[:2]
    factor = min(1.0, OVERLAY_WIDTH / width)
    size = (max(1, round(width * factor)), max(1, round(height * factor)))
    return cv2.resize(array, size, interpolation=interpolation)


def frame_counts(score: np.ndarray, mask: np.ndarray) -> SparseCounts:
    """Per-frame pixel histogram, as :class:`MetricsAccumulator` would pool it."""
    histogram = PixelScoreHistogram()
    histogram.update(score, mask)
    return SparseCounts.of(histogram)


def _evaluate_frame(job: tuple[EvalFrame, bool]) -> FrameOutcome:
    frame, want_overlay = job
    processor: FrameProcessor = _STATE["processor"]
    try:
        processed = processor.process(
            frame.image,
            frame.T_station_camera,
            frame.sun_direction,
            frame.sun_strength,
            frame.bodies,
            reference=frame.reference,
        )
        methods = {
            name: MethodOutcome(
                counts=frame_counts(result.score, frame.mask),
                area=float(result.area),
                anomalous=bool(result.anomalous),
                timings_ms=dict(result.timings_ms),
                overlap=object_overlap(result.mask, frame.mask) if frame.is_anomalous else None,
            )
            for name, result in processed.results.items()
        }
    except Exception as error:
        raise EvaluationError(f"frame {frame.name} (index {frame.index}): {error}") from None
    overlay = None
    if want_overlay:
        overlay = Overlay(
            image=_small(frame.image, cv2.INTER_AREA),
            truth=_small((frame.mask == POSITIVE_CLASS).astype(np.uint8), cv2.INTER_NEAREST),
            masks={n: _small(r.mask, cv2.INTER_NEAREST) for n, r in processed.results.items()},
            scores={n: _small(r.score, cv2.INTER_AREA) for n, r in processed.results.items()},
        )
    return FrameOutcome(
        index=frame.index,
        name=frame.name,
        anomaly=frame.anomaly,
        truth_anomalous=frame.is_anomalous,
        methods=methods,
        timings_ms=dict(processed.timings_ms),
        overlay=overlay,
    )


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
        self.image_scores.append(outcome.area)
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


@dataclass
class EvaluationResult:
    """Metrics, breakdowns, curves, latencies and overlays of one run."""

    input: str
    kind: str
    name: str
    split: str | None
    frames: int
    config: EvaluationConfig
    metrics: dict[str, AlloMetrics]
    per_type: dict[str, dict[str, Any]]
    detection: dict[str, dict[str, int]]
    curves: dict[str, Curve | None]
    latency_ms: dict[str, dict[str, float]]
    wall_s: float
    overlays: list[FrameOutcome]

    @property
    def frames_per_second(self) -> float:
        """Frames processed per wall-clock second (all jobs together)."""
        return self.frames / self.wall_s if self.wall_s > 0 else float("nan")


def _jobs(
    source: FrameSource, indices: list[int], overlays: int, chosen: dict[str, int]
) -> Iterator[tuple[EvalFrame, bool]]:
    taken = 0
    for frame in source.frames(indices):
        group = frame.anomaly if frame.is_anomalous else NORMAL_GROUP
        want = taken < overlays and chosen[group] < OVERLAYS_PER_GROUP
        if want:
            chosen[group] += 1
            taken += 1
        yield frame, want


def _curve(accumulator: MetricsAccumulator) -> Curve | None:
    pixels = accumulator.pixels
    if pixels.positives.sum() == 0 or pixels.negatives.sum() == 0:
        return None
    return pixels.curve()


def evaluate(
    source: FrameSource | str | PathLike[str],
    config: EvaluationConfig | None = None,
) -> EvaluationResult:
    """Run the detectors over a split of a sequence or bag and compute the ALLO metrics.

    Parameters
    ----------
    source : FrameSource or path-like
        Input (see :func:`rosbag_tools.frames.open_source`).
    config : EvaluationConfig, optional
        Options (defaults: all three methods, default parameters, test split).

    Returns
    -------
    EvaluationResult

    Raises
    ------
    EvaluationError
        For a frame that fails (naming it) or an invalid option.
    rosbag_tools.frames.FrameSourceError
        For an input that cannot be read.
    """
    config = config or EvaluationConfig()
    if not isinstance(source, FrameSource):
        source = open_source(source)
    split = config.split if config.split is not None else source.default_split()
    indices = source.select(split, config.limit)
    setup = RendererSetup(source.mesh, source.camera, config.ref_scale, config.shadows)
    tallies: dict[str, dict[str, Tally]] = {m: defaultdict(Tally) for m in config.methods}
    samples: dict[str, list[float]] = defaultdict(list)
    overlays: list[FrameOutcome] = []
    overlaps: dict[tuple[str, str], list[ObjectOverlap]] = defaultdict(list)
    frames_by_group: dict[str, int] = defaultdict(int)
    chosen: dict[str, int] = defaultdict(int)
    clock = RunClock()
    outcomes = run_frames(
        _jobs(source, indices, config.overlays, chosen),
        len(indices),
        initializer=_init_evaluation,
        initargs=(setup, config.params, tuple(config.methods)),
        work=_evaluate_frame,
        jobs=config.jobs,
        progress=config.progress,
        desc="evaluate",
        clock=clock,
    )
    try:
        for outcome in outcomes:
            frames_by_group[outcome.group] += 1
            for name, method in outcome.methods.items():
                tallies[name][outcome.group].add(method, outcome.truth_anomalous)
                if method.overlap is not None:
                    overlaps[outcome.group, name].append(method.overlap)
                for stage, value in method.timings_ms.items():
                    samples[f"{name}/{stage}"].append(value)
            for stage, value in outcome.timings_ms.items():
                samples[stage].append(value)
            if outcome.overlay is not None:
                overlays.append(outcome)
    finally:
        if config.jobs == 1:
            release_worker_state()
    metrics, curves, detection = {}, {}, {}
    for name in config.methods:
        accumulator = merged_accumulator(list(tallies[name].values()))
        metrics[name] = accumulator.compute()
        curves[name] = _curve(accumulator)
        detection[name] = confusion(list(tallies[name].values()))
    per_type = {}
    types = sorted(g for g in frames_by_group if g != NORMAL_GROUP)
    for anomaly in types:
        per_type[anomaly] = {
            "frames": frames_by_group[anomaly],
            "normal_frames": frames_by_group.get(NORMAL_GROUP, 0),
            "methods": {
                name: merged_accumulator(
                    [tallies[name][anomaly]]
                    + ([tallies[name][NORMAL_GROUP]] if NORMAL_GROUP in tallies[name] else [])
                )
                .compute()
                .as_dict()
                for name in config.methods
            },
            "localisation": {name: summarise(overlaps[anomaly, name]) for name in config.methods},
        }
    return EvaluationResult(
        input=str(source.path),
        kind=source.kind,
        name=source.name,
        split=split,
        frames=len(indices),
        config=config,
        metrics=metrics,
        per_type=per_type,
        detection=detection,
        curves=curves,
        latency_ms=latency_stats(samples),
        wall_s=clock.seconds,
        overlays=overlays,
    )
