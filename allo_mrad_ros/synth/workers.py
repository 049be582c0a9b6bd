"""Rendering planned frames in this process or in worker processes, in plan order, and
writing each rendered frame to the sequence.

Both sequence kinds (single frames, :mod:`~.generator`, and arm trajectories,
:mod:`~.trajectory_output`) render a list of plans with one synthesizer per process; the
outputs come back in the order of the plans whatever the number of workers, so the files
written from them do not depend on ``jobs``.
"""

from __future__ import annotations

import multiprocessing
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from allo_mrad_ros.geometry import pose_components
from allo_mrad_ros.sequence import GroundTruthObject, SequenceMeta, SequenceWriter
from allo_mrad_ros.synth.config import SynthConfig
from allo_mrad_ros.synth.frames import FrameOutput, FrameSynthesizer, camera_intrinsics
from allo_mrad_ros.synth.trajectory_frames import TrajectoryFrameOutput

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


@dataclass(frozen=True)
class SequenceJob:
    """One sequence to generate, as :func:`~.generator.generate` was asked for it.

    Attributes
    ----------
    config : SynthConfig
        Settings.
    root : pathlib.Path
        Output folder.
    seed : int
        Sequence seed.
    mesh : pathlib.Path
        Station model file.
    jobs : int
        Worker processes; 1 renders in this process.
    overwrite : bool
        Replace a sequence already in ``root``.
    progress : bool
        Show a progress bar on stderr.
    backend : str or None
        OpenGL backend; None chooses.
    start_ns : int
        Stamp of the first frame.
    """

    config: SynthConfig
    root: Path
    seed: int
    mesh: Path
    jobs: int
    overwrite: bool
    progress: bool
    backend: str | None
    start_ns: int

    def rendered(
        self,
        kind: type[FrameSynthesizer],
        render: Render,
        plans: Sequence[object],
        chunksize: int = 1,
    ) -> Iterator[Any]:
        """The outputs of ``plans``, lazily and in their order.

        Parameters
        ----------
        kind : type
            The synthesizer class (:class:`~.frames.FrameSynthesizer` or a subclass), built
            as ``kind(config, seed, mesh, backend)`` once per process.
        render : callable
            The method that renders one plan, taken from the class.
        plans : sequence
            What to render.
        chunksize : int
            Plans handed to a worker at a time.
        """
        arguments = (self.config, self.seed, self.mesh, self.backend)
        if self.jobs == 1:
            outputs = _in_process(kind, render, arguments, plans)
        else:
            outputs = _in_workers(kind, render, arguments, plans, self.jobs, chunksize)
        if not self.progress:
            return outputs
        from tqdm import tqdm

        return tqdm(
            outputs,
            total=len(plans),
            desc=f"allo-synth {self.config.name}",
            unit="frame",
            file=sys.stderr,
        )

    def writer(self, objects: Sequence[GroundTruthObject] | None = None) -> SequenceWriter:
        """The sequence's writer; with ``objects`` (even none) a version 2 sequence."""
        meta = SequenceMeta(
            name=f"allo-synth {self.config.name} seed {self.seed}",
            camera=camera_intrinsics(self.config),
            rate_hz=self.config.rate_hz,
            mesh=self.mesh,
        )
        return SequenceWriter(
            self.root,
            meta,
            overwrite=self.overwrite,
            start_ns=self.start_ns,
            png_compression=self.config.png_compression,
            objects=objects,
        )


def _in_process(
    kind: type[FrameSynthesizer],
    render: Render,
    arguments: tuple[SynthConfig, int, Path, str | None],
    plans: Sequence[object],
) -> Iterator[Any]:
    synthesizer = kind(*arguments)
    try:
        for plan in plans:
            yield render(synthesizer, plan)
    finally:
        synthesizer.close()


def _in_workers(
    kind: type[FrameSynthesizer],
    render: Render,
    arguments: tuple[SynthConfig, int, Path, str | None],
    plans: Sequence[object],
    jobs: int,
    chunksize: int,
) -> Iterator[Any]:
    config, seed, mesh, backend = arguments
    # Spawned workers start clean: no OpenGL state inherited from this process.
    context = multiprocessing.get_context("spawn")
    with context.Pool(
        jobs, initializer=_init_worker, initargs=(kind, render, config, seed, str(mesh), backend)
    ) as pool:
        yield from pool.imap(_work, plans, chunksize=chunksize)


def write_output(
    writer: SequenceWriter,
    output: FrameOutput | TrajectoryFrameOutput,
    *,
    camera: int,
    anomaly: str,
    **columns: object,
) -> None:
    """Add a rendered frame to ``writer``: its images, its reported pose, its sky and extra
    columns, with the ``camera`` and ``anomaly`` its kind of sequence gives it and any other
    :meth:`~allo_mrad_ros.sequence.SequenceWriter.add_frame` fields in ``columns``."""
    plan = output.plan
    position, quaternion = pose_components(output.T_reported)
    writer.add_frame(
        split=plan.split,
        camera=camera,
        image=output.image,
        mask=output.mask,
        reference=output.reference,
        anomaly=anomaly,
        position=position,
        quaternion=quaternion,
        sun_direction=output.sky.sun_direction,
        sun_strength=plan.sun_strength,
        earth=output.sky.earth,
        moon=output.sky.moon,
        name=plan.name,
        extra=output.extra,
        **columns,
    )
