"""``allo-bag ablate``: the paper's Table II sweeps of MRAD as one table.

One parameter varies at a time around the baseline (the chosen profile with its overrides):

- grid: 1 (no grid), 2, 3, 4, 6, 8 cells per side;
- tolerance: 25, 50, 100, 150, 200 % of the baseline tolerance (50 on the paper's scale);
- kernel: local-std window of 5, 10, 20, 30 % of the cell;
- blur SD: 2, 5, 10 px.

Each frame's reference is rendered once and reused by every parameter set (through
``FrameProcessor.process(reference=...)``), and identical parameter sets (the baseline
appears in every sweep) are run once.
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
from allo_mrad_ros.metrics import AlloMetrics, MetricsAccumulator
from allo_mrad_ros.processing import FrameProcessor
from allo_mrad_ros.render import DEFAULT_SCALE, DEFAULT_SHADOWS
from rosbag_tools.evaluate import (
    MethodOutcome,
    RendererSetup,
    Tally,
    build_renderer,
    frame_counts,
    merged_accumulator,
)
from rosbag_tools.frames import EvalFrame, FrameSource, open_source
from rosbag_tools.parallel import RunClock, run_frames

GRIDS = (1, 2, 3, 4, 6, 8)
TOLERANCE_PERCENT = (25, 50, 100, 150, 200)
KERNEL_FRACTIONS = (0.05, 0.10, 0.20, 0.30)
BLUR_SIGMAS = (2.0, 5.0, 10.0)


class AblationError(RuntimeError):
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
class AblationResult:
    """The whole table and the run's facts."""

    input: str
    kind: str
    name: str
    split: str | None
    frames: int
    baseline: MradParams
    ref_scale: float
    rows: list[AblationRow] = field(default_factory=list)
    configs: int = 0
    render_ms_median: float = 0.0
    wall_s: float = 0.0
    jobs: int = 1


_STATE: dict[str, Any] = {}


def _init_ablation(setup: RendererSetup, param_sets: tuple[MradParams, ...]) -> None:
    _release()
    renderer = build_renderer(setup)
    _STATE["renderer"] = renderer
    _STATE["processors"] = [FrameProcessor(renderer, p, ("MRAD",)) for p in param_sets]


def _release() -> None:
    renderer = _STATE.pop("renderer", None)
    _STATE.clear()
    if renderer is not None:
        renderer.close()


def _ablate_frame(frame: EvalFrame) -> tuple[bool, float, list[MethodOutcome]]:
    processors: list[FrameProcessor] = _STATE["processors"]
    try:
        reference, render_ms = frame.reference, 0.0
        if reference is None:
            start = time.perf_counter()
            reference = processors[0].render_reference(
                frame.T_station_camera, frame.sun_direction, frame.sun_strength, frame.bodies
            )
            render_ms = 1e3 * (time.perf_counter() - start)
        outcomes = []
        for processor in processors:
            result = processor.process(
                frame.image,
                frame.T_station_camera,
                frame.sun_direction,
                frame.sun_strength,
                frame.bodies,
                reference=reference,
            )
            mrad = result.results["MRAD"]
            outcomes.append(
                MethodOutcome(
                    counts=frame_counts(mrad.score, frame.mask),
                    area=float(mrad.area),
                    anomalous=bool(mrad.anomalous),
                    timings_ms={"total": result.timings_ms["MRAD"]},
                )
            )
    except Exception as error:
        raise AblationError(f"frame {frame.name} (index {frame.index}): {error}") from None
    return frame.is_anomalous, render_ms, outcomes


def ablate(
    source: FrameSource | str | PathLike[str],
    *,
    base: MradParams | None = None,
    ref_scale: float = DEFAULT_SCALE,
    shadows: bool = DEFAULT_SHADOWS,
    split: str | None = None,
    limit: int | None = None,
    jobs: int = 1,
    progress: bool = True,
) -> AblationResult:
    """Run the Table II sweeps over a split of a sequence or bag.

    Parameters
    ----------
    source : FrameSource or path-like
        Input (see :func:`rosbag_tools.frames.open_source`).
    base : MradParams, optional
        Baseline parameters (default: the project defaults, the paper's optimum).
    ref_scale, shadows
        Reference rendering, as for ``evaluate``.
    split : str, optional
        Split to use; None means ``test`` if present, else every frame.
    limit : int, optional
        Use at most this many frames, evenly spread over the split.
    jobs : int
        Worker processes.
    progress : bool
        Show a progress bar.

    Returns
    -------
    AblationResult

    Raises
    ------
    AblationError
        For a frame that fails (naming it) or an invalid option.
    """
    base = base or MradParams()
    if not (0 < ref_scale <= 1):
        raise AblationError(f"ref_scale must be in (0, 1], got {ref_scale!r}")
    if not isinstance(source, FrameSource):
        source = open_source(source)
    chosen_split = split if split is not None else source.default_split()
    indices = source.select(chosen_split, limit)
    points = sweep_points(base)
    unique = list(dict.fromkeys(p.params for p in points))
    setup = RendererSetup(source.mesh, source.camera, ref_scale, shadows)
    tallies = [Tally() for _ in unique]
    times: list[list[float]] = [[] for _ in unique]
    render_times: list[float] = []
    clock = RunClock()
    results: Iterator = run_frames(
        source.frames(indices),
        len(indices),
        initializer=_init_ablation,
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
            _release()
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
        input=str(source.path),
        kind=source.kind,
        name=source.name,
        split=chosen_split,
        frames=len(indices),
        baseline=base,
        ref_scale=ref_scale,
        rows=rows,
        configs=len(unique),
        render_ms_median=float(np.median(render_times)) if render_times else 0.0,
        wall_s=clock.seconds,
        jobs=jobs,
    )
