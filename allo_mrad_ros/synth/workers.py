"""Rendering planned frames in this process or in worker processes, in plan order.

Both sequence kinds (single frames, :mod:`~.generator`, and arm trajectories,
:mod:`~.trajectory_output`) render a list of plans with one synthesizer per process; the
outputs come back in the order of the plans whatever the number of workers, so the files
written from them do not depend on ``jobs``.
"""

from __future__ import annotations

import multiprocessing
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from allo_mrad_ros.synth.config import SynthConfig
from allo_mrad_ros.synth.frames import FrameSynthesizer

Render = Callable[[Any, Any], Any]
"""A synthesizer method taken from its class (``FrameSynthesizer.synthesize``): called with
the synthesizer and one plan, it returns that plan's output."""

_WORKER: tuple[FrameSynthesizer, Render] | None = None


def _init_worker(
    kind: type[FrameSynthesizer],
    render: Render,
    config: SynthConfig,
    seed: int,
    mesh: str,
    backend: str | None,
) -> None:
    global _WORKER
    _WORKER = (kind(config, seed, mesh, backend), render)


def _work(plan: object) -> object:
    synthesizer, render = _WORKER
    return render(synthesizer, plan)


def _outputs(
    kind: type[FrameSynthesizer],
    render: Render,
    config: SynthConfig,
    seed: int,
    mesh: Path,
    plans: Sequence[object],
    jobs: int,
    backend: str | None,
    chunksize: int,
) -> Iterator[Any]:
    if jobs == 1:
        synthesizer = kind(config, seed, mesh, backend)
        try:
            for plan in plans:
                yield render(synthesizer, plan)
        finally:
            synthesizer.close()
        return
    # Spawned workers start clean: no OpenGL state inherited from this process.
    context = multiprocessing.get_context("spawn")
    with context.Pool(
        jobs, initializer=_init_worker, initargs=(kind, render, config, seed, str(mesh), backend)
    ) as pool:
        yield from pool.imap(_work, plans, chunksize=chunksize)


def rendered(
    kind: type[FrameSynthesizer],
    render: Render,
    config: SynthConfig,
    seed: int,
    mesh: Path,
    plans: Sequence[object],
    *,
    jobs: int,
    backend: str | None,
    progress: bool,
    chunksize: int = 1,
) -> Iterator[Any]:
    """The outputs of ``plans``, lazily and in their order.

    Parameters
    ----------
    kind : type
        The synthesizer class (:class:`~.frames.FrameSynthesizer` or a subclass), built as
        ``kind(config, seed, mesh, backend)`` once per process.
    render : callable
        The method that renders one plan, taken from the class.
    config, seed, mesh, backend
        As for :func:`~.generator.generate`.
    plans : sequence
        What to render.
    jobs : int
        Worker processes; 1 renders in this process.
    progress : bool
        Show a progress bar on stderr.
    chunksize : int
        Plans handed to a worker at a time.
    """
    outputs = _outputs(kind, render, config, seed, mesh, plans, jobs, backend, chunksize)
    if not progress:
        return outputs
    from tqdm import tqdm

    return tqdm(
        outputs,
        total=len(plans),
        desc=f"allo-synth {config.name}",
        unit="frame",
        file=sys.stderr,
    )
