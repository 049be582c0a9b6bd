"""``allo-bag ablate``: the paper's Table II sweeps of MRAD as one table.

One parameter varies at a time around the baseline (the chosen profile with its overrides):

- grid: 1 (no grid), 2, 3, 4, 6, 8 cells per side;
- tolerance: 25, 50, 100, 150, 200 % of the baseline tolerance (50 on the paper's scale);
- kernel: local-std window of 5, 10, 20, 30 % of the cell;
- blur SD: 2, 5, 10 px.

Each frame's reference is rendered once and reused by every parameter set (one
:class:`~allo_mrad_ros.pipeline.Pipeline` per set, sharing the reference provider), and
identical parameter sets (the baseline appears in every sweep) are run once.
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, field
from os import PathLike
from typing import Any

import numpy as np

from allo_mrad_ros.detector import MradParams
from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.evaluation.evaluate import (
    MethodOutcome,
    Tally,
    WorkerSetup,
    check_run_options,
    merged_accumulator,
    release_worker_state,
    start_worker,
)
from allo_mrad_ros.evaluation.parallel import RunClock, run_frames
from allo_mrad_ros.evaluation.sources import EvalFrame, FrameSource, RunFacts, open_sequence
from allo_mrad_ros.metrics import AlloMetrics, MetricsAccumulator
from allo_mrad_ros.pipeline import Pipeline, PipelineConfig

GRIDS = (1, 2, 3, 4, 6, 8)
TOLERANCE_PERCENT = (25, 50, 100, 150, 200)
KERNEL_FRACTIONS = (0.05, 0.10, 0.20, 0.30)
BLUR_SIGMAS = (2.0, 5.0, 10.0)


class AblationError(InvalidInput):
    """An ablation cannot run (bad option) or a frame failed (the message names it)."""


@dataclass(frozen=True)
class SweepPoint:
    """One row of the table: a sweep, its setting and the parameters it runs."""

    sweep: str
    label: str
    value: float
    params: MradParams
    is_baseline: bool


def sweep_points(base: MradParams) -> list[SweepPoint]:
    """The rows of Table II around ``base``, in table order.

    Raises
    ------
    AblationError
        If a swept value is invalid with the other baseline parameters.
    """
    points = []

    def add(sweep: str, label: str, value: float, **change: Any) -> None:
        try:
            params = base.replace(**change)
        except ValueError as error:
            raise AblationError(f"sweep {sweep} {label}: {error}") from None
        points.append(SweepPoint(sweep, label, value, params, params == base))

    for grid in GRIDS:
        add("grid", "no grid" if grid == 1 else f"{grid}x{grid}", grid, grid=grid)
    for percent in TOLERANCE_PERCENT:
        tolerance = base.tolerance * percent / 100.0
        add("tolerance", f"{percent} % ({tolerance:g})", tolerance, tolerance=tolerance)
    for fraction in KERNEL_FRACTIONS:
        add("kernel", f"{100 * fraction:g} %", fraction, kernel_fraction=fraction)
    for sigma in BLUR_SIGMAS:
        add("blur SD", f"{sigma:g} px", sigma, blur_sigma=sigma)
    return points


@dataclass
class AblationRow:
    """Metrics of one sweep point."""

    sweep: str
    label: str
    value: float
    is_baseline: bool
    metrics: AlloMetrics
    mrad_ms_median: float


@dataclass
class AblationResult(RunFacts):
    """The whole table and the run's facts."""

    baseline: MradParams
    reference_scale: float
    rows: list[AblationRow] = field(default_factory=list)
    configs: int = 0
    render_ms_median: float = 0.0
    wall_s: float = 0.0
    jobs: int = 1


_PIPELINES: list[Pipeline] = []


def _start_ablation(setup: WorkerSetup, param_sets: tuple[MradParams, ...]) -> None:
    base = start_worker(setup)
    _PIPELINES[:] = [base.with_config(setup.config.replace(params=p)) for p in param_sets]


def _ablate_frame(frame: EvalFrame) -> tuple[bool, float, list[MethodOutcome]]:
    try:
        reference, render_ms = frame.reference, 0.0
        if reference is None:
            start = time.perf_counter()
            reference = _PIPELINES[0].render(frame.view)
            render_ms = 1e3 * (time.perf_counter() - start)
        outcomes = []
        for pipeline in _PIPELINES:
            detected = pipeline.detect(frame.image, reference)
            outcomes.append(
                MethodOutcome.of(
                    detected.results["MRAD"], frame.mask, {"total": detected.timings_ms["MRAD"]}
                )
            )
    except (ValueError, RuntimeError) as error:
        raise AblationError(f"frame {frame.name} (index {frame.index}): {error}") from None
    return frame.is_anomalous, render_ms, outcomes


def ablate(
    source: FrameSource | str | PathLike[str],
    *,
    config: PipelineConfig | None = None,
    split: str | None = None,
    limit: int | None = None,
    jobs: int = 1,
    progress: bool = True,
) -> AblationResult:
    """Run the Table II sweeps over a split of a sequence or bag.

    ``source``, ``split``, ``limit``, ``jobs`` and ``progress`` are as for
    :func:`~allo_mrad_ros.evaluation.evaluate.evaluate`; ``config`` gives the reference
    rendering and the baseline parameters (default: the project defaults; its methods are
    ignored, the sweeps are of MRAD).

    Raises
    ------
    AblationError
        For a frame that fails (naming it) or an invalid option.
    """
    config = (config or PipelineConfig()).replace(methods=("MRAD",))
    base = config.params
    check_run_options(jobs, limit)
    if not isinstance(source, FrameSource):
        source = open_sequence(source)
    chosen_split = split if split is not None else source.default_split()
    indices = source.select(chosen_split, limit)
    points = sweep_points(base)
    unique = list(dict.fromkeys(p.params for p in points))
    setup = WorkerSetup(source.mesh, source.camera, config)
    tallies = [Tally() for _ in unique]
    times: list[list[float]] = [[] for _ in unique]
    render_times: list[float] = []
    clock = RunClock()
    results: Iterator = run_frames(
        source.frames(indices),
        len(indices),
        initializer=_start_ablation,
        initargs=(setup, tuple(unique)),
        work=_ablate_frame,
        jobs=jobs,
        progress=progress,
        desc="ablate",
        clock=clock,
    )
    try:
        for truth, render_ms, outcomes in results:
            render_times.append(render_ms)
            for i, outcome in enumerate(outcomes):
                tallies[i].add(outcome, truth)
                times[i].append(outcome.timings_ms["total"])
    finally:
        if jobs == 1:
            release_worker_state()
            _PIPELINES.clear()
    metrics: dict[MradParams, AlloMetrics] = {}
    medians: dict[MradParams, float] = defaultdict(float)
    for i, params in enumerate(unique):
        accumulator: MetricsAccumulator = merged_accumulator([tallies[i]])
        metrics[params] = accumulator.compute()
        medians[params] = float(np.median(times[i])) if times[i] else float("nan")
    rows = [
        AblationRow(p.sweep, p.label, p.value, p.is_baseline, metrics[p.params], medians[p.params])
        for p in points
    ]
    return AblationResult(
        **vars(RunFacts.of(source, chosen_split, indices)),
        baseline=base,
        reference_scale=config.render.reference_scale,
        rows=rows,
        configs=len(unique),
        render_ms_median=float(np.median(render_times)) if render_times else 0.0,
        wall_s=clock.seconds,
        jobs=jobs,
    )
