"""Offline evaluation (``allo-bag evaluate``): MRAD, PAD and RXD on every frame of a split.

Every frame goes through :meth:`allo_mrad_ros.pipeline.Pipeline.process`, the step the
detector node runs: the reference is rendered at the frame's pose with the input's own
station model, then each method detects. The workers count each frame's pixels per distinct
score (exactly what :class:`~allo_mrad_ros.metrics.MetricsAccumulator` would add), so only
counts travel between processes; counts add up, so the totals equal a single accumulator
fed every frame.

Per anomaly type, the metrics use that type's anomalous frames together with all normal
frames (the usual per-category reading).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, field
from os import PathLike
from typing import Any

import cv2
import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.evaluation.parallel import RunClock, run_frames
from allo_mrad_ros.evaluation.sources import (
    EvalFrame,
    FrameSource,
    RunFacts,
    open_sequence,
)
from allo_mrad_ros.evaluation.tally import (
    NORMAL_GROUP,
    FrameOutcome,
    MethodOutcome,
    Overlay,
    Tally,
    confusion,
    latency_stats,
    merged_accumulator,
)
from allo_mrad_ros.localisation import ObjectOverlap, summarise
from allo_mrad_ros.metrics import (
    POSITIVE_CLASS,
    AlloMetrics,
    Curve,
)
from allo_mrad_ros.pipeline import Pipeline, PipelineConfig
from allo_mrad_ros.staging import hold_point

ALL_METHODS = ("MRAD", "PAD", "RXD")
OVERLAY_WIDTH = 320
OVERLAYS_PER_GROUP = 2


class EvaluationError(InvalidInput):
    """Evaluation cannot run (bad option) or a frame failed (the message names it)."""


@dataclass(frozen=True)
class EvaluationConfig:
    """Options of :func:`evaluate`.

    ``pipeline``: render settings, detector parameters and methods (default: all three
    methods); ``split``: the split to evaluate (None: ``test`` if present, else every frame);
    ``limit``: at most this many frames, evenly spread over the split; ``jobs``: worker
    processes; ``overlays``: example frames in the overlay grid (0: none); ``progress``: show
    a progress bar.
    """

    pipeline: PipelineConfig = field(default_factory=lambda: PipelineConfig(methods=ALL_METHODS))
    split: str | None = None
    limit: int | None = None
    jobs: int = 1
    overlays: int = 8
    progress: bool = True

    def __post_init__(self) -> None:
        check_run_options(self.jobs, self.limit)
        if self.overlays < 0:
            raise EvaluationError(f"overlays must be >= 0, got {self.overlays}")


def check_run_options(jobs: int, limit: int | None) -> None:
    """Validate the worker count and the frame limit of a run (evaluate and ablate)."""
    if jobs < 1:
        raise EvaluationError(f"jobs must be at least 1, got {jobs}")
    if limit is not None and limit < 1:
        raise EvaluationError(f"limit must be at least 1, got {limit}")


# ----------------------------------------------------------------- worker side
@dataclass(frozen=True)
class WorkerSetup:
    """What a worker process needs to build its pipeline (picklable)."""

    mesh: Any
    camera: CameraIntrinsics
    config: PipelineConfig


_STATE: dict[str, Any] = {}


def start_worker(setup: WorkerSetup) -> Pipeline:
    """Build this process's pipeline (one reference provider per process)."""
    release_worker_state()
    pipeline = Pipeline.open(setup.camera, mesh=setup.mesh, config=setup.config)
    _STATE["pipeline"] = pipeline
    return pipeline


def worker_pipeline() -> Pipeline:
    """The pipeline :func:`start_worker` built in this process."""
    return _STATE["pipeline"]


def release_worker_state() -> None:
    """Close this process's pipeline (after an in-process run)."""
    pipeline = _STATE.pop("pipeline", None)
    _STATE.clear()
    if pipeline is not None:
        pipeline.close()


def _small(array: np.ndarray, interpolation: int) -> np.ndarray:
    height, width = array.shape[:2]
    factor = min(1.0, OVERLAY_WIDTH / width)
    size = (max(1, round(width * factor)), max(1, round(height * factor)))
    return cv2.resize(array, size, interpolation=interpolation)


def _evaluate_frame(job: tuple[EvalFrame, bool]) -> FrameOutcome:
    frame, want_overlay = job
    try:
        processed = worker_pipeline().process(
            frame.image, frame.view, reference=frame.reference, time_s=frame.stamp_ns / 1e9
        )
        methods = {
            name: MethodOutcome.of(result, frame.mask, dict(result.timings_ms))
            for name, result in processed.results.items()
        }
    except (ValueError, RuntimeError) as error:
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


@dataclass
class EvaluationResult(RunFacts):
    """Metrics, breakdowns, curves, latencies and overlays of one run."""

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


def evaluate(
    source: FrameSource | str | PathLike[str],
    config: EvaluationConfig | None = None,
) -> EvaluationResult:
    """Run the detectors over a split of a sequence or bag and compute the ALLO metrics.

    Parameters
    ----------
    source : FrameSource or path-like
        Input; a path opens a sequence folder (bags: :func:`rosbag_tools.bag_source.open_source`).
    config : EvaluationConfig, optional
        Options (defaults: all three methods, default parameters, test split).

    Returns
    -------
    EvaluationResult

    Raises
    ------
    EvaluationError
        For a frame that fails (naming it) or an invalid option.
    allo_mrad_ros.evaluation.sources.FrameSourceError
        For an input that cannot be read.
    """
    config = config or EvaluationConfig()
    if not isinstance(source, FrameSource):
        source = open_sequence(source)
    split = config.split if config.split is not None else source.default_split()
    indices = source.select(split, config.limit)
    methods = config.pipeline.methods
    setup = WorkerSetup(source.mesh, source.camera, config.pipeline)
    tallies: dict[str, dict[str, Tally]] = {m: defaultdict(Tally) for m in methods}
    samples: dict[str, list[float]] = defaultdict(list)
    overlays: list[FrameOutcome] = []
    overlaps: dict[tuple[str, str], list[ObjectOverlap]] = defaultdict(list)
    frames_by_group: dict[str, int] = defaultdict(int)
    chosen: dict[str, int] = defaultdict(int)
    clock = RunClock()
    outcomes = run_frames(
        _jobs(source, indices, config.overlays, chosen),
        len(indices),
        initializer=start_worker,
        initargs=(setup,),
        work=_evaluate_frame,
        jobs=config.jobs,
        progress=config.progress,
        desc="evaluate",
        clock=clock,
    )
    try:
        for outcome in outcomes:
            hold_point("evaluate-frame")
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
    for name in methods:
        accumulator = merged_accumulator(list(tallies[name].values()))
        metrics[name] = accumulator.compute()
        curves[name] = accumulator.curve()
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
                for name in methods
            },
            "localisation": {name: summarise(overlaps[anomaly, name]) for name in methods},
        }
    return EvaluationResult(
        **vars(RunFacts.of(source, split, indices)),
        config=config,
        metrics=metrics,
        per_type=per_type,
        detection=detection,
        curves=curves,
        latency_ms=latency_stats(samples),
        wall_s=clock.seconds,
        overlays=overlays,
    )
