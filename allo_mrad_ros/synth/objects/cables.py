"""Cables (a tube along a random spline, with connectors) and a detached handrail."""

from __future__ import annotations

import numpy as np

from .base import Part
from .shapes import catmull_rom, rod, tube


def random_walk(rng: np.random.Generator, count: int, step: float, stiffness: float) -> np.ndarray:
    """Control points of a cable: each step keeps some of the previous direction."""
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    points = [np.zeros(3)]
    for _ in range(count - 1):
        turn = rng.normal(size=3)
        direction = stiffness * direction + (1.0 - stiffness) * turn / np.linalg.norm(turn)
        direction /= np.linalg.norm(direction)
        points.append(points[-1] + step * direction)
    return np.asarray(points)


def _connector(end: np.ndarray, direction: np.ndarray, radius: float) -> list:
    direction = direction / np.linalg.norm(direction)
    body = rod(end - 0.01 * direction, end + 0.06 * direction, 2.2 * radius, 16)
    collar = rod(end + 0.06 * direction, end + 0.075 * direction, 2.6 * radius, 16)
    return [body, collar]


def cable(rng: np.random.Generator) -> list[Part]:
    """A loose power or data cable: a tube along a random spline, a connector at each end."""
    length = rng.uniform(1.5, 3.0)
    radius = rng.uniform(0.012, 0.03)
    controls = random_walk(rng, int(rng.integers(5, 9)), 1.0, rng.uniform(0.3, 0.7))
    path = catmull_rom(controls, 14)
    path *= length / np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    jacket = rng.choice(["black_cable", "orange_cable", "white_cloth", "grey_plastic"])
    connectors = _connector(path[0], path[0] - path[1], radius) + _connector(
        path[-1], path[-1] - path[-2], radius
    )
    parts = [Part(tube(path, radius, 14), str(jacket), smooth=True)]
    parts += [Part(mesh, "aluminium", smooth=True) for mesh in connectors]
    return parts


def tether_hook(rng: np.random.Generator) -> list[Part]:
    """An EVA safety-tether hook (carabiner) with a length of webbing strap."""
    size = rng.uniform(0.12, 0.18)
    # The hook body: a rounded "D" along a closed loop, left open where the gate is.
    t = np.linspace(0.15, 2 * np.pi - 0.15, 60)
    loop = np.stack(
        [0.6 * size * np.cos(t), size * np.sin(t) * (1.0 + 0.25 * np.cos(t)), 0 * t], -1
    )
    rod_radius = rng.uniform(0.008, 0.012)
    body = tube(loop, rod_radius, 12)
    gate = rod(loop[-1], loop[0], 0.7 * rod_radius, 10)
    # Webbing: a thin tube leaving the hook's far end, drifting in a gentle curve.
    strap_len = rng.uniform(0.5, 1.0)
    controls = random_walk(rng, 5, 1.0, 0.7)
    controls -= controls[0]
    controls[:, 0] -= np.arange(5) * 1.5  # away from the hook, along -x
    path = catmull_rom(controls, 10)
    path *= strap_len / np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    path += np.array([-0.6 * size - rod_radius, 0.0, 0.0])
    strap = tube(path, rng.uniform(0.012, 0.018), 8)
    strap_material = "yellow_plastic" if rng.random() < 0.5 else "white_cloth"
    return [
        Part(strap, strap_material, smooth=True),
        Part(body, "aluminium", smooth=True),
        Part(gate, "dark_metal", smooth=True),
    ]


def handrail(rng: np.random.Generator) -> list[Part]:
    """A handrail broken off the station: a yellow bar with its standoffs."""
    length = rng.uniform(0.6, 1.2)
    lift = rng.uniform(0.1, 0.14)
    bar_radius = rng.uniform(0.016, 0.022)
    bend = rng.uniform(-0.1, 0.1)  # a bent rail: the middle pushed out of line
    path = catmull_rom(np.array([[0.0, 0, 0], [length / 2, bend, 0], [length, 0, 0]]), 16)
    parts = [Part(tube(path, bar_radius, 14), "handrail_yellow", smooth=True)]
    posts = int(rng.integers(2, 4))
    for i in range(posts):
        x = path[round(i * (len(path) - 1) / (posts - 1))]
        foot = x - np.array([0.0, 0.0, lift])
        parts.append(Part(rod(x, foot, 0.8 * bar_radius, 12), "handrail_yellow", smooth=True))
        pad = rod(foot, foot - np.array([0.0, 0.0, 0.012]), 0.035, 16)
        parts.append(Part(pad, "aluminium", smooth=False))
    # The broken end: a short stub of bare metal.
    tip = path[-1]
    direction = path[-1] - path[-2]
    stub = rod(tip, tip + 0.04 * direction / np.linalg.norm(direction), 0.7 * bar_radius, 10)
    parts.append(Part(stub, "aluminium", smooth=False))
    return parts
