"""Procedural anomaly objects, built deterministically from trimesh primitives and a seed.

Sixteen types cover the families of ALLO's test set: thermal blankets, cables, tools lost
during EVAs, an astronaut glove, CubeSats and small satellites, debris. Five more are opt-in
(:data:`OPT_IN_TYPES`): a dark glossy helmet visor and the path-traced bench's hard kinds
(a thin cable, black foil, small debris, a panel painted like the station; :mod:`.hard`). A
sequence gets them only when its settings name them, so the sequences of every existing
preset keep their frames. Each builder draws
its dimensions from a seeded NumPy generator, so ``build_anomaly(kind, seed)`` always gives
the same object; sizes are those of the real things (a 1U CubeSat is 10 cm).
"""

from __future__ import annotations

from collections.abc import Callable
from types import MappingProxyType

import numpy as np

from allo_mrad_ros.errors import InvalidInput

from .base import (
    COLOURS,
    DEFAULT_COLOUR,
    MATERIALS,
    AnomalyObject,
    Part,
    sample_surface,
    sample_triangles,
)
from .cables import cable, handrail, tether_hook
from .glossy import dark_visor
from .hard import black_foil, small_debris, station_patch, thin_cable
from .satellites import cubesat_1u, cubesat_3u, cubesat_6u, helicopter, smallsat
from .sheets import blanket_crumpled, blanket_curved, debris_panel, mli_strip
from .tools import drill, glove, pistol_grip_tool, wrench

Builder = Callable[[np.random.Generator], list[Part]]

ANOMALY_TYPES: MappingProxyType[str, Builder] = MappingProxyType(
    {
        "blanket_crumpled": blanket_crumpled,
        "blanket_curved": blanket_curved,
        "mli_strip": mli_strip,
        "cable": cable,
        "tether_hook": tether_hook,
        "handrail": handrail,
        "drill": drill,
        "pistol_grip_tool": pistol_grip_tool,
        "wrench": wrench,
        "glove": glove,
        "cubesat_1u": cubesat_1u,
        "cubesat_3u": cubesat_3u,
        "cubesat_6u": cubesat_6u,
        "smallsat": smallsat,
        "helicopter": helicopter,
        "debris_panel": debris_panel,
    }
)
"""Object type name to builder, in a fixed order: the types a sequence draws by default."""

OPT_IN_TYPES: MappingProxyType[str, Builder] = MappingProxyType(
    {
        "dark_visor": dark_visor,
        "thin_cable": thin_cable,
        "black_foil": black_foil,
        "small_debris": small_debris,
        "station_patch": station_patch,
    }
)
"""Types drawn only when a sequence names them (adding one to the default draw would
change the frame plan of every existing preset)."""

KNOWN_TYPES: MappingProxyType[str, Builder] = MappingProxyType({**ANOMALY_TYPES, **OPT_IN_TYPES})
"""Every type :func:`build_anomaly` and a sequence's ``anomaly_types`` accept."""

DARK_TYPES = frozenset({"dark_visor", "black_foil"})
"""Types whose own materials are dark (diffuse albedo under 10 %)."""

SHEET_TYPES = frozenset({"blanket_crumpled", "blanket_curved", "mli_strip", "black_foil"})
"""Types made of open sheets (zero thickness); all others are closed solids."""


class ObjectError(InvalidInput):
    """An unknown object type or colour, or a bad seed."""


def build_anomaly(
    kind: str, seed: int, colour: str = DEFAULT_COLOUR, scale: float = 1.0
) -> AnomalyObject:
    """Build one anomaly object.

    Parameters
    ----------
    kind : str
        A key of :data:`KNOWN_TYPES`.
    seed : int
        Non-negative seed of the object's own random generator.
    colour : str
        ``default`` for the object's own materials, or a key of :data:`COLOURS` to recolour
        its main part (ALLO's colour variant).
    scale : float
        Size factor in (0, 1] (ALLO's scale variant); 1 keeps the real object's size.

    Returns
    -------
    AnomalyObject
        The object, centred on its bounding box, in metres.

    Raises
    ------
    ObjectError
        For an unknown kind or colour, a negative seed or a scale outside (0, 1].
    """
    if kind not in KNOWN_TYPES:
        raise ObjectError(f"unknown anomaly type {kind!r}; known: {', '.join(KNOWN_TYPES)}")
    if colour != DEFAULT_COLOUR and colour not in COLOURS:
        raise ObjectError(f"unknown colour {colour!r}; known: default, {', '.join(COLOURS)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ObjectError(f"seed must be a non-negative integer, got {seed!r}")
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0 < scale <= 1:
        raise ObjectError(f"scale must be a number in (0, 1], got {scale!r}")
    parts = KNOWN_TYPES[kind](np.random.default_rng(int(seed)))
    low = np.min([p.mesh.bounds[0] for p in parts], axis=0)
    high = np.max([p.mesh.bounds[1] for p in parts], axis=0)
    centre = (low + high) / 2.0
    for part in parts:
        part.mesh.apply_translation(-centre)
        if scale != 1:
            part.mesh.apply_scale(float(scale))
    return AnomalyObject(
        kind=kind, seed=int(seed), colour=colour, parts=tuple(parts), scale=float(scale)
    )


__all__ = [
    "ANOMALY_TYPES",
    "COLOURS",
    "DARK_TYPES",
    "DEFAULT_COLOUR",
    "KNOWN_TYPES",
    "MATERIALS",
    "OPT_IN_TYPES",
    "SHEET_TYPES",
    "AnomalyObject",
    "ObjectError",
    "Part",
    "build_anomaly",
    "sample_surface",
    "sample_triangles",
]
