"""Generate an ALLO-like sequence: plan, render (optionally in parallel), write.

Frames are planned from the seed, rendered by :class:`~.frames.FrameSynthesizer` (in this
process, or in ``jobs`` worker processes with one renderer each) and written in playback
order by :class:`~allo_mrad_ros.sequence.SequenceWriter`. Every frame draws from its own
random stream, so the output is byte-identical for the same seed, whatever ``jobs`` is.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from dataclasses import asdict, dataclass, fields, is_dataclass
from os import PathLike
from pathlib import Path

from allo_mrad_ros.ephemeris import EPOCH_2030
from allo_mrad_ros.staging import hold_point
from allo_mrad_ros.synth.config import SynthConfig, SynthError
from allo_mrad_ros.synth.frames import FrameSynthesizer
from allo_mrad_ros.synth.planning import FramePlan, plan_frames
from allo_mrad_ros.synth.workers import SequenceJob, write_output

START_NS = int(EPOCH_2030.timestamp()) * 10**9
"""Stamp of the first frame: 2030-01-01T00:00:00Z, as for imported ALLO splits."""
GENERATION_FILE = "generation.json"
"""Provenance written next to ``sequence.yaml``: settings, seed and composition."""


@dataclass(frozen=True)
class GenerationReport:
    """What :func:`generate` wrote and how long it took.

    Attributes
    ----------
    root : pathlib.Path
        The sequence folder.
    composition : dict
        Per split: ``frames``, ``normal``, ``anomalous``, ``cameras``, counts per object
        type, depth, scale and colour, and how many objects fell back to another depth or
        scale.
    frames : int
        Frames written.
    seconds : float
        Wall time, including setup.
    frames_per_minute : float
        Throughput over the whole run.
    """

    root: Path
    composition: dict
    frames: int
    seconds: float
    frames_per_minute: float


def _composition(outputs: list[tuple[FramePlan, dict]], config: SynthConfig) -> dict:
    result: dict[str, dict] = {}
    for split, spec in config.splits.items():
        rows = [(plan, extra) for plan, extra in outputs if plan.split == split]
        anomalous = [(p, e) for p, e in rows if p.is_anomalous]
        result[split] = {
            "frames": len(rows),
            "normal": len(rows) - len(anomalous),
            "anomalous": len(anomalous),
            "cameras": spec.cameras,
            "per_type": dict(sorted(Counter(p.anomaly for p, _ in anomalous).items())),
            "per_depth_m": {
                str(k): v for k, v in sorted(Counter(e["depth_m"] for _, e in anomalous).items())
            },
            "depth_fallbacks": sum(e["depth_m"] != p.depth_m for p, e in anomalous),
            "per_scale": {
                str(k): v for k, v in sorted(Counter(e["scale"] for _, e in anomalous).items())
            },
            "scale_fallbacks": sum(e["scale"] != p.scale for p, e in anomalous),
            "per_colour": dict(sorted(Counter(e["colour"] for _, e in anomalous).items())),
        }
    return result


def _config_dict(config: SynthConfig) -> dict:
    result = {}
    for item in fields(config):
        value = getattr(config, item.name)
        if item.name == "trajectory" and value is None:
            continue  # not a trajectory sequence: generation.json as before trajectories
        if item.name == "splits":
            value = {split: asdict(spec) for split, spec in value.items()}
        elif is_dataclass(value):
            value = asdict(value)
        result[item.name] = value
    return result


def generate(
    config: SynthConfig,
    out: str | PathLike[str],
    seed: int = 0,
    *,
    mesh: str | PathLike[str] | None = None,
    jobs: int = 1,
    overwrite: bool = False,
    progress: bool = True,
    backend: str | None = None,
) -> GenerationReport:
    """Generate a sequence into ``out``.

    Parameters
    ----------
    config : SynthConfig
        Settings (see :func:`~.config.preset`).
    out : path-like
        Output folder.
    seed : int
        Sequence seed, non-negative; the same seed gives identical files.
    mesh : path-like, optional
        Station model file; default the package's ``meshes/station.glb``. It is copied to
        ``out/meshes/``.
    jobs : int
        Worker processes (one renderer each); 1 renders in this process.
    overwrite : bool
        Replace a sequence already in ``out``.
    progress : bool
        Show a progress bar on stderr.
    backend : str, optional
        OpenGL backend (``osmesa`` or ``egl``); None chooses.

    Returns
    -------
    GenerationReport
        Composition and throughput.

    Raises
    ------
    SynthError
        For invalid arguments or a frame whose placement rules cannot be met.
    SequenceError
        If ``out`` holds a sequence and ``overwrite`` is False.
    """
    if not isinstance(config, SynthConfig):
        raise SynthError(f"config must be a SynthConfig, got {type(config).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
        raise SynthError(f"seed must be a non-negative integer, got {seed!r}")
    if isinstance(jobs, bool) or not isinstance(jobs, int) or not 1 <= jobs <= 64:
        raise SynthError(f"jobs must be an integer in 1..64, got {jobs!r}")
    if mesh is None:
        from allo_mrad_ros.resources import share_path

        mesh = share_path("meshes", "station.glb")
    mesh = Path(mesh)
    if not mesh.is_file():
        raise SynthError(f"station mesh not found: {mesh}")
    start = time.perf_counter()
    root = Path(out)
    job = SequenceJob(
        config=config,
        root=root,
        seed=seed,
        mesh=mesh,
        jobs=jobs,
        overwrite=overwrite,
        progress=progress,
        backend=backend,
        start_ns=START_NS,
    )
    if config.trajectory is None:
        written_frames, composition = _generate_frames(job)
    else:
        from allo_mrad_ros.synth.trajectory_output import generate_trajectories

        written_frames, composition = generate_trajectories(job)
    provenance = {
        "generator": "allo-synth",
        "seed": seed,
        "mesh": mesh.name,
        "config": _config_dict(config),
        "composition": composition,
    }
    (root / GENERATION_FILE).write_text(json.dumps(provenance, indent=2, default=list) + "\n")
    seconds = time.perf_counter() - start
    return GenerationReport(
        root=root,
        composition=composition,
        frames=written_frames,
        seconds=seconds,
        frames_per_minute=60.0 * written_frames / seconds if seconds > 0 else 0.0,
    )


def _generate_frames(job: SequenceJob) -> tuple[int, dict]:
    """Render and write a sequence of single frames (see :func:`generate`).

    Returns
    -------
    tuple
        Frames written, and the composition per split.
    """
    config = job.config
    plans = plan_frames(config, job.seed)
    written: list[tuple[FramePlan, dict]] = []
    outputs = job.rendered(FrameSynthesizer, FrameSynthesizer.synthesize, plans)
    with job.writer() as writer:
        for output in outputs:
            write_output(writer, output, camera=output.plan.camera, anomaly=output.plan.anomaly)
            hold_point("generate-frame")
            written.append((output.plan, output.extra))
    return len(written), _composition(written, config)
