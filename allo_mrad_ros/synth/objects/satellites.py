"""CubeSats (1U, 3U, 6U with deployed panels), a small satellite and a small helicopter."""

from __future__ import annotations

import numpy as np
import trimesh

from .base import Part
from .shapes import rod, rotation_about, slab, transformed

U = 0.1  # one CubeSat unit, metres
RAIL = 0.0085  # CubeSat rail width


def _cubesat(rng: np.random.Generator, units: tuple[int, int, int], wings: int) -> list[Part]:
    """A CubeSat of ``units`` (x, y, z) cells with ``wings`` solar panels hinged at its top."""
    size = np.asarray(units, dtype=np.float64) * U
    size[2] += 0.0135 * units[2]  # a 1U is 113.5 mm tall
    # Body panels sit just inside the rails.
    parts = [Part(slab((0, 0, 0), size - 0.002), "solar_cells")]
    half = size / 2
    for sx in (-1, 1):
        for sy in (-1, 1):
            centre = (sx * (half[0] - RAIL / 2), sy * (half[1] - RAIL / 2), 0.0)
            rail = slab(centre, (RAIL, RAIL, size[2] + 0.014))
            parts.append(Part(rail, "aluminium"))
    opening = rng.uniform(np.radians(60), np.radians(100))
    sides = [(1, 0), (-1, 0), (0, 1), (0, -1)][:wings]
    for dx, dy in sides:
        # Panel as long as the side it folds against, hinged at the top edge.
        panel_len = size[2]
        panel_w = size[1] if dx else size[0]
        panel = slab((0, 0, -panel_len / 2), (0.003, panel_w, panel_len))
        if dy:
            panel = transformed(panel, rotation_about((0, 0, 1), np.pi / 2))
        axis = np.array([-dy, dx, 0.0])
        hinge = np.array([dx * half[0], dy * half[1], half[2]])
        parts.append(Part(transformed(panel, rotation_about(axis, -opening), hinge), "solar_cells"))
    if rng.random() < 0.7:  # a tape-spring UHF antenna
        length = rng.uniform(0.15, 0.5)
        parts.append(
            Part(rod((0, 0, -half[2]), (length * 0.3, 0, -half[2] - length), 0.003, 6), "aluminium")
        )
    return parts


def cubesat_1u(rng: np.random.Generator) -> list[Part]:
    """A 1U CubeSat with four deployed panels."""
    return _cubesat(rng, (1, 1, 1), 4)


def cubesat_3u(rng: np.random.Generator) -> list[Part]:
    """A 3U CubeSat with two or four deployed panels."""
    return _cubesat(rng, (1, 1, 3), int(rng.choice([2, 4])))


def cubesat_6u(rng: np.random.Generator) -> list[Part]:
    """A 6U (2 x 1 x 3) CubeSat with two or four deployed panels."""
    return _cubesat(rng, (2, 1, 3), int(rng.choice([2, 4])))


def smallsat(rng: np.random.Generator) -> list[Part]:
    """A small satellite: gold-wrapped bus, two solar wings on booms, a dish antenna."""
    bus = rng.uniform(0.4, 0.7, 3)
    parts = [Part(slab((0, 0, 0), bus), "gold_foil")]
    wing_len = rng.uniform(0.6, 1.0)
    wing_w = rng.uniform(0.35, 0.5)
    tilt = rng.uniform(-0.6, 0.6)
    for side in (-1, 1):
        root = np.array([0.0, side * bus[1] / 2, 0.0])
        boom_end = root + np.array([0.0, side * 0.15, 0.0])
        parts.append(Part(rod(root, boom_end, 0.012, 10), "aluminium"))
        panel = slab((0, side * wing_len / 2, 0), (wing_w, wing_len, 0.02))
        panel = transformed(panel, rotation_about((0, 1, 0), tilt), boom_end)
        parts.append(Part(panel, "solar_cells"))
    dish_r = rng.uniform(0.12, 0.22)
    cone = trimesh.creation.cone(radius=dish_r, height=0.5 * dish_r, sections=24)
    cone.apply_transform(np.diag([1.0, 1.0, -1.0, 1.0]))  # opening upwards
    if cone.volume < 0:  # in case the mirror turned it inside out
        cone.invert()
    cone.apply_translation((0.0, 0.0, bus[2] / 2 + 0.5 * dish_r + 0.05))
    parts.append(Part(rod((0, 0, bus[2] / 2), (0, 0, bus[2] / 2 + 0.05), 0.015, 10), "aluminium"))
    parts.append(Part(cone, "white_paint", smooth=True))
    return parts


def helicopter(rng: np.random.Generator) -> list[Part]:
    """A small rotorcraft like Ingenuity: body, mast, two counter-rotating rotors, legs."""
    body = slab((0, 0, 0), (0.14, 0.2, 0.16))
    parts = [Part(body, "gold_foil")]
    mast_top = 0.08 + rng.uniform(0.2, 0.3)
    parts.append(Part(rod((0, 0, 0.08), (0, 0, mast_top), 0.012, 12), "carbon"))
    radius = rng.uniform(0.5, 0.6)
    for level, height in enumerate((mast_top - 0.1, mast_top - 0.02)):
        angle = rng.uniform(0, np.pi)
        for blade in (0, 1):
            r = rotation_about((0, 0, 1), angle + blade * np.pi)
            slab_mesh = slab((radius / 2, 0, 0), (radius, 0.07 - 0.015 * level, 0.008))
            parts.append(Part(transformed(slab_mesh, r, (0, 0, height)), "carbon"))
    parts.append(Part(slab((0, 0, mast_top + 0.01), (0.16, 0.1, 0.006)), "solar_cells"))
    for k in range(4):
        a = np.pi / 4 + k * np.pi / 2
        top = np.array([0.06 * np.cos(a), 0.08 * np.sin(a), -0.06])
        foot = top + np.array([0.3 * np.cos(a), 0.3 * np.sin(a), -0.35])
        parts.append(Part(rod(top, foot, 0.007, 8), "carbon"))
    return parts
