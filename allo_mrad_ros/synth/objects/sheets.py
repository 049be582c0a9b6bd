"""Thermal blankets (crumpled and curved MLI sheets, torn strips) and a debris panel."""

from __future__ import annotations

import numpy as np

from .base import Part
from .shapes import catmull_rom, grid_sheet, rotation_about, star_plate


def _waves(
    rng: np.random.Generator,
    u: np.ndarray,
    v: np.ndarray,
    count: int,
    amplitude: float,
    wavelength: tuple[float, float],
) -> np.ndarray:
    """Sum of plane waves with random directions: smooth, random folds."""
    height = np.zeros_like(u)
    for _ in range(count):
        angle = rng.uniform(0.0, np.pi)
        k = 2 * np.pi / rng.uniform(*wavelength)
        phase = rng.uniform(0.0, 2 * np.pi)
        height += (
            rng.uniform(0.3, 1.0)
            * amplitude
            * np.sin(k * (np.cos(angle) * u + np.sin(angle) * v) + phase)
        )
    return height


def blanket_crumpled(rng: np.random.Generator) -> list[Part]:
    """A crumpled multi-layer insulation blanket torn off a module (gold or silver foil)."""
    width, height = rng.uniform(0.7, 1.4), rng.uniform(0.5, 1.0)
    u, v = np.meshgrid(
        np.linspace(-width / 2, width / 2, 33),
        np.linspace(-height / 2, height / 2, 25),
        indexing="ij",
    )
    # Crumpling shortens the sheet in its plane and throws it out of plane.
    squeeze = rng.uniform(0.75, 0.9)
    z = _waves(rng, u, v, 6, 0.025, (0.12, 0.4)) + _waves(rng, u, v, 3, 0.05, (0.5, 1.2))
    # Creases: folded ridges where a smooth wave is replaced by its absolute value.
    z += 0.04 * np.abs(_waves(rng, u, v, 2, 1.0, (0.3, 0.7)))
    points = np.stack([u * squeeze, v * squeeze, z], -1)
    # Most blankets also curl up along one side.
    points[..., 2] += rng.uniform(-0.5, 0.5) * (u / width) ** 2 * width
    material = "gold_foil" if rng.random() < 0.5 else "silver_foil"
    return [Part(grid_sheet(points), material, smooth=True)]


def blanket_curved(rng: np.random.Generator) -> list[Part]:
    """A curved white beta-cloth blanket that kept the shape of the module it covered."""
    radius = rng.uniform(0.35, 0.7)
    span = rng.uniform(np.radians(70), np.radians(200))
    length = rng.uniform(0.5, 1.1)
    theta, s = np.meshgrid(
        np.linspace(-span / 2, span / 2, 41),
        np.linspace(-length / 2, length / 2, 21),
        indexing="ij",
    )
    wrinkle = _waves(rng, theta * radius, s, 4, 0.008, (0.15, 0.4))
    r = radius + wrinkle
    # A slight twist: the blanket came off unevenly.
    twist = rng.uniform(-0.4, 0.4) * s / length
    points = np.stack([r * np.sin(theta + twist), s, r * np.cos(theta + twist) - radius], -1)
    material = "white_cloth" if rng.random() < 0.7 else "silver_foil"
    return [Part(grid_sheet(points), material, smooth=True)]


def mli_strip(rng: np.random.Generator) -> list[Part]:
    """A long torn strip of MLI, twisting and curling as it drifts."""
    length = rng.uniform(1.2, 2.2)
    width = rng.uniform(0.12, 0.25)
    controls = np.cumsum(np.vstack([np.zeros(3), rng.normal(0.0, 1.0, (4, 3))]), axis=0)
    controls[:, 0] += np.linspace(0.0, 4.0, 5)  # mostly along x: a strip, not a ball
    spine = catmull_rom(controls, 10)
    spine *= length / np.linalg.norm(np.diff(spine, axis=0), axis=1).sum()
    tangent = np.gradient(spine, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    side = np.cross(tangent, [0.0, 0.0, 1.0])
    side /= np.maximum(np.linalg.norm(side, axis=1, keepdims=True), 1e-9)
    turns = rng.uniform(0.5, 2.0) * np.pi
    angles = np.linspace(0.0, turns, len(spine))
    across = np.stack(
        [rotation_about(t, a) @ s for t, s, a in zip(tangent, side, angles, strict=True)]
    )
    w = np.linspace(-width / 2, width / 2, 5)
    points = spine[:, None, :] + w[None, :, None] * across[:, None, :]
    material = "silver_foil" if rng.random() < 0.6 else "gold_foil"
    return [Part(grid_sheet(points), material, smooth=True)]


def debris_panel(rng: np.random.Generator) -> list[Part]:
    """A broken-off honeycomb panel: jagged outline, bent along one side."""
    count = 36
    size = rng.uniform(0.35, 0.7)
    angles = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    # A roughly rectangular outline (the panel's shape) with a torn edge on some sides.
    aspect = rng.uniform(0.5, 1.0)
    box = 1.0 / np.maximum(np.abs(np.cos(angles)), np.abs(np.sin(angles)) / aspect)
    radii = size * np.minimum(box, 1.4) * rng.uniform(0.9, 1.0, count)
    torn = np.abs(np.sin(angles + rng.uniform(0, np.pi))) > 0.6
    radii[torn] *= rng.uniform(0.7, 1.0, int(torn.sum()))
    plate = star_plate(radii, rings=6, thickness=rng.uniform(0.015, 0.035))
    vertices = plate.vertices.copy()
    # Bend: beyond the fold line the panel curls by up to ~50 degrees.
    fold = rng.uniform(-0.2, 0.3) * size
    bend = rng.uniform(0.4, 1.6) / size
    beyond = np.maximum(vertices[:, 0] - fold, 0.0)
    vertices[:, 2] += 0.5 * bend * beyond**2
    plate.vertices = vertices
    # Panels are white-painted on the outside; a stripe of gold tape on some.
    material = "white_paint" if rng.random() < 0.6 else "aluminium"
    return [Part(plate, material, smooth=False)]
