"""Dark glossy objects: what per-cell colour statistics find hardest to tell from shadow.

A helmet under its lowered sun visor is, to a camera, a dark mirror: almost no diffuse
albedo, so against a shadowed or dimly lit station it has the station's colour, and what
sets it apart is the gloss, a small sharp highlight of the Sun or the arm lamp. The
rasteriser has no environment map, so the reflection it draws is that highlight alone.
"""

from __future__ import annotations

import numpy as np

from .base import Part
from .shapes import ellipsoid, rod, transformed


def dark_visor(rng: np.random.Generator) -> list[Part]:
    """An EVA helmet behind its dark visor: glossy dome, dark rim, hinge bosses, neck ring.

    The visor (the first part, which colour variants recolour) covers the front and top of
    the helmet; the shell around it is dark carbon, so the whole object is dark.
    """
    width = rng.uniform(0.15, 0.18)  # half-widths: a helmet is 30-36 cm across
    depth = width * rng.uniform(1.05, 1.15)
    height = width * rng.uniform(1.1, 1.25)
    visor = ellipsoid((width, depth, height), subdivisions=3)
    # The shell is the back half: an ellipsoid pushed backwards out of the visor.
    shell = transformed(
        ellipsoid((0.97 * width, 0.95 * depth, 0.97 * height), 2), None, (0.0, 0.2 * depth, 0.0)
    )
    rim_height = -0.55 * height
    rim = rod((0.0, 0.0, rim_height - 0.012), (0.0, 0.0, rim_height + 0.012), 0.9 * width, 32)
    neck = rod((0.0, 0.0, -0.75 * height), (0.0, 0.0, -0.95 * height), 0.7 * width, 24)
    boss = rng.uniform(0.018, 0.026)
    hinges = [
        rod((s * 0.98 * width, 0.0, 0.0), (s * (0.98 * width + 0.02), 0.0, 0.0), boss, 16)
        for s in (-1.0, 1.0)
    ]
    return [
        Part(visor, "visor_black", smooth=True),
        Part(shell, "carbon", smooth=True),
        Part(rim, "carbon"),
        Part(neck, "dark_metal", smooth=True),
        *(Part(hinge, "dark_metal") for hinge in hinges),
    ]
