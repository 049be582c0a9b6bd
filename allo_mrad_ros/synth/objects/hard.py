"""Objects of the kinds per-cell colour statistics find hardest, for the path-traced bench.

* :func:`thin_cable` - a bare cable 12-44 mm thick and metres long: about 1-4 pixels wide
  at the bench's resolution and distances, its grey, black or white jacket already in most
  cells' colours;
* :func:`black_foil` - a crumpled sheet of black Kapton (albedo 3 %), dark over a lit
  surface and as dark as space in front of space when unlit;
* :func:`small_debris` - a bracket with a bolt, 7-13 cm: under 100 pixels at 4 m;
* :func:`station_patch` - a bent panel that the generator paints with the station's own
  dominant material (:func:`~allo_mrad_ros.synth.hard_kinds.station_palette`).

All four are opt-in (:data:`~.OPT_IN_TYPES`): sequences of the earlier presets keep their
frame plans.
"""

from __future__ import annotations

import numpy as np
import trimesh

from .base import Part
from .cables import random_walk
from .shapes import catmull_rom, rod, tube
from .sheets import blanket_crumpled, debris_panel

THIN_CABLE_RADIUS_M = (0.006, 0.022)
"""Radius range of :func:`thin_cable`: about 1-4 px wide at 4 m on a 512 px wide ALLO camera;
the bench's generator keeps only placements whose silhouette is 1-4 px wide."""


def thin_cable(rng: np.random.Generator) -> list[Part]:
    """A thin loose cable: a tube along a random spline, 2-4 m, no connectors."""
    length = rng.uniform(2.0, 4.0)
    radius = rng.uniform(*THIN_CABLE_RADIUS_M)
    controls = random_walk(rng, int(rng.integers(4, 7)), 1.0, rng.uniform(0.5, 0.8))
    path = catmull_rom(controls, 16)
    path *= length / np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    jacket = rng.choice(["grey_plastic", "black_cable", "white_cloth"])
    return [Part(tube(path, radius, 8), str(jacket), smooth=True)]


def black_foil(rng: np.random.Generator) -> list[Part]:
    """A crumpled sheet of black Kapton foil (a blanket's outer layer)."""
    sheet = blanket_crumpled(rng)[0]
    return [Part(sheet.mesh, "black_kapton", smooth=True)]


def small_debris(rng: np.random.Generator) -> list[Part]:
    """A small bracket with its bolt: an L of two plates, 7-13 cm."""
    size = rng.uniform(0.07, 0.13)
    thick = 0.006
    base = trimesh.creation.box(extents=[size, 0.5 * size, thick])
    upright = trimesh.creation.box(extents=[thick, 0.5 * size, 0.7 * size])
    upright.apply_translation([size / 2, 0.0, 0.35 * size])
    bolt = rod((-0.2 * size, 0.0, 0.0), (-0.2 * size, 0.0, 0.3 * size), 0.012, 12)
    material = str(rng.choice(["aluminium", "white_paint", "grey_plastic"]))
    return [Part(base, material), Part(upright, material), Part(bolt, "dark_metal", smooth=True)]


def station_patch(rng: np.random.Generator) -> list[Part]:
    """A bent panel; the generator gives it the station's own material."""
    return debris_panel(rng)
