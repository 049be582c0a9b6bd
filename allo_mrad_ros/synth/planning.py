"""What each frame will show, decided before anything is rendered.

All random choices that do not depend on a render (camera, day, Sun strength, object type,
depth, colour, per-frame seeds) are drawn here from the sequence seed, so a frame's content
does not depend on which worker renders it or in which order.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from allo_mrad_ros.synth.config import SynthConfig
from allo_mrad_ros.synth.objects import ANOMALY_TYPES, COLOURS, DEFAULT_COLOUR

# Independent random streams derived from the sequence seed.
STREAM_PLAN, STREAM_POSES, STREAM_MATERIALS, STREAM_FRAME, STREAM_CAMERA = range(5)
STREAM_LIGHT, STREAM_WEAR = 5, 6  # per frame: the query's Sun, the object's wear
STREAM_DEVELOP = 7  # per frame: the path tracer's view transform and exposure
# The path-traced bench's departures: the Cycles materials (per sequence), the Earth-shine
# (per frame) and a hard kind's paint (per frame).
STREAM_PT_MATERIALS, STREAM_PT_LIGHT, STREAM_PT_KIND = 8, 9, 10


def stream(seed: int, kind: int, *index: int) -> np.random.Generator:
    """The random generator of one stream (and one frame) of a sequence seed."""
    return np.random.default_rng(np.random.SeedSequence([seed, kind, *index]))


@dataclass(frozen=True)
class FramePlan:
    """The decided content of one frame.

    Attributes
    ----------
    index : int
        Position in the sequence (playback order).
    split : str
        ``train``, ``val`` or ``test``.
    camera : int
        Base pose index within the split.
    day : int
        Day of 2030 (sets the Sun, Earth and Moon).
    sun_strength : float
        Relative Sun strength.
    anomaly : str
        Object type, empty for a normal frame.
    depth_m : float
        Requested depth offset of the object (0 for normal frames).
    colour : str
        ``default`` or a colour variant name.
    scale : float
        Scale of the object (1 unless the frame is a scale variant).
    object_seed : int
        Seed the object is built from.
    seed : int
        Sequence seed; the frame's own stream is ``stream(seed, STREAM_FRAME, index)``.
    """

    index: int
    split: str
    camera: int
    day: int
    sun_strength: float
    anomaly: str
    depth_m: float
    colour: str
    object_seed: int
    seed: int
    scale: float = 1.0

    @property
    def is_anomalous(self) -> bool:
        """Whether the frame gets an anomaly object."""
        return bool(self.anomaly)

    @property
    def name(self) -> str:
        """Image file stem: index and content, unique within the sequence."""
        return f"{self.index:06d}_{self.anomaly or 'normal'}"


def balanced(values: Sequence, count: int, rng: np.random.Generator) -> list:
    """``count`` values, each used equally often (within one), in random order."""
    if count == 0:
        return []
    values = list(values)
    repeats = -(-count // len(values))
    pool = [values[i] for _ in range(repeats) for i in rng.permutation(len(values))][:count]
    return [pool[i] for i in rng.permutation(count)]


def plan_frames(config: SynthConfig, seed: int) -> list[FramePlan]:
    """Plan every frame of a sequence.

    Within a split, object types, depth offsets and cameras are balanced (each used equally
    often, within one), normal and anomalous frames are spread over all cameras, and frames
    play back in order of day.

    Parameters
    ----------
    config : SynthConfig
        The sequence settings.
    seed : int
        Sequence seed.

    Returns
    -------
    list of FramePlan
        Splits in ``train``, ``val``, ``test`` order.
    """
    rng = stream(seed, STREAM_PLAN)
    types = config.anomaly_types or tuple(ANOMALY_TYPES)
    weights = np.asarray(config.sun_weights, dtype=np.float64)
    weights = weights / weights.sum()
    colours = tuple(COLOURS)
    plans: list[FramePlan] = []
    for split, spec in config.splits.items():
        kinds = [""] * spec.normal + balanced(types, spec.anomalous, rng)
        depths = [0.0] * spec.normal + balanced(config.depths_m, spec.anomalous, rng)
        cameras = balanced(range(spec.cameras), spec.normal, rng) + balanced(
            range(spec.cameras), spec.anomalous, rng
        )
        days = rng.integers(config.days[0], config.days[1] + 1, spec.frames)
        strengths = rng.choice(len(weights), size=spec.frames, p=weights)
        recolour = rng.random(spec.frames) < config.colour_probability
        colour_index = rng.integers(len(colours), size=spec.frames)
        object_seeds = rng.integers(0, 2**31 - 1, spec.frames)
        rescale = rng.random(spec.frames) < config.scale_probability
        scale_index = rng.integers(len(config.scales), size=spec.frames)
        order = sorted(range(spec.frames), key=lambda i: (days[i], cameras[i], i))
        for i in order:
            anomalous = bool(kinds[i])
            plans.append(
                FramePlan(
                    index=len(plans),
                    split=split,
                    camera=int(cameras[i]),
                    day=int(days[i]),
                    sun_strength=float(config.sun_strengths[strengths[i]]),
                    anomaly=kinds[i],
                    depth_m=float(depths[i]),
                    colour=colours[colour_index[i]]
                    if anomalous and recolour[i]
                    else DEFAULT_COLOUR,
                    object_seed=int(object_seeds[i]) if anomalous else 0,
                    seed=seed,
                    scale=float(config.scales[scale_index[i]]) if anomalous and rescale[i] else 1.0,
                )
            )
    return plans
