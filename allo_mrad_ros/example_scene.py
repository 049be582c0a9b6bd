"""A built-in synthetic station view for the demo, the benchmark and the tests.

It is not a renderer: just enough structure to exercise the detector the way space imagery
does (a large dark background, bright textured modules, grey metal, a saturated glare
patch) without any data files.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class ExamplePair:
    """A reference, a query with a pasted object, and the object's mask."""

    reference: np.ndarray
    query: np.ndarray
    clean_query: np.ndarray
    object_mask: np.ndarray


def station_view(height: int, width: int, seed: int = 0) -> np.ndarray:
    """Return an H x W x 3 uint8 station-like image on black space."""
    rng = np.random.default_rng(seed)
    image = np.zeros((height, width, 3), dtype=np.uint8)
    s = min(height, width) / 1080.0
    # Pressurised modules: white insulation with quilting texture.
    for _ in range(3):
        x0, y0 = int(rng.uniform(0.1, 0.6) * width), int(rng.uniform(0.25, 0.6) * height)
        w, h = int(rng.uniform(0.2, 0.35) * width), int(rng.uniform(0.08, 0.14) * height)
        base = rng.uniform(170, 225)
        patch = base + 12 * np.sin(np.arange(w)[None, :] / (9 * s + 1)) + rng.normal(0, 4, (h, w))
        shade = np.linspace(1.0, 0.6, h)[:, None]
        block = np.clip(patch * shade, 0, 255)
        tint = np.array([1.0, 0.98, 0.93])
        image[y0 : y0 + h, x0 : x0 + w] = (block[..., None] * tint)[: height - y0, : width - x0]
    # Solar arrays: dark blue cells with a grid of bright lines.
    for side in (0.02, 0.72):
        x0, y0 = int(side * width), int(0.1 * height)
        w, h = int(0.25 * width), int(0.3 * height)
        cells = np.zeros((h, w, 3), dtype=np.float32)
        cells[:] = (25, 35, 70)
        cells[:: max(2, int(24 * s)), :] = (120, 120, 130)
        cells[:, :: max(2, int(24 * s))] = (120, 120, 130)
        image[y0 : y0 + h, x0 : x0 + w] = np.clip(cells + rng.normal(0, 3, cells.shape), 0, 255)
    # Truss: grey metal (R = G = B) bars.
    y = int(0.7 * height)
    cv2.rectangle(image, (0, y), (width - 1, y + max(2, int(18 * s))), (140, 140, 140), -1)
    for x in range(0, width, max(4, int(90 * s))):
        cv2.line(
            image, (x, y), (x + int(40 * s), y + int(18 * s)), (200, 200, 200), max(1, int(3 * s))
        )
    # Gold foil radiator and a saturated glare spot.
    cv2.rectangle(
        image,
        (int(0.42 * width), int(0.75 * height)),
        (int(0.58 * width), int(0.92 * height)),
        (210, 160, 60),
        -1,
    )
    cv2.circle(
        image, (int(0.85 * width), int(0.82 * height)), max(2, int(40 * s)), (255, 255, 255), -1
    )
    return image


def paste_object(
    image: np.ndarray,
    seed: int = 1,
    centre: tuple[float, float] = (0.5, 0.17),
    size: float = 0.1,
) -> tuple[np.ndarray, np.ndarray]:
    """Paste a loose gold-foil blanket; return the image and its mask.

    ``centre`` is (x, y) as fractions of the width and height (default: in the dark sky
    above the station); ``size`` is the blanket's radius as a fraction of the short side.
    """
    rng = np.random.default_rng(seed)
    height, width = image.shape[:2]
    centre = np.array([centre[0] * width, centre[1] * height])
    radius = size * min(height, width)
    angles = np.sort(rng.uniform(0, 2 * np.pi, 9))
    radii = radius * rng.uniform(0.6, 1.0, 9)
    polygon = centre + np.column_stack([np.cos(angles), np.sin(angles)]) * radii[:, None]
    mask = np.zeros((height, width), dtype=np.uint8)
    cv2.fillPoly(mask, [polygon.astype(np.int32)], 255)
    texture = rng.normal(0, 18, (height, width)).astype(np.float32)
    texture = cv2.GaussianBlur(texture, (0, 0), 2.0)
    foil = np.stack([200 + texture, 150 + texture, 40 + 0.5 * texture], axis=-1)
    out = image.copy()
    out[mask > 0] = np.clip(foil[mask > 0], 0, 255).astype(np.uint8)
    return out, mask


def camera_effects(image: np.ndarray, noise_sd: float, shift_px: int, seed: int = 2) -> np.ndarray:
    """Add Gaussian sensor noise and a pure translation of ``shift_px`` pixels (x and y)."""
    rng = np.random.default_rng(seed)
    shifted = np.roll(image, (shift_px, shift_px), axis=(0, 1))
    noisy = shifted.astype(np.float32) + rng.normal(0, noise_sd, image.shape).astype(np.float32)
    return np.clip(noisy, 0, 255).astype(np.uint8)


def example_pair(height: int = 1080, width: int = 1920, seed: int = 0) -> ExamplePair:
    """Reference, query with object (noise SD 2, 2-px shift), the clean query, the mask."""
    reference = station_view(height, width, seed)
    with_object, mask = paste_object(reference, seed + 1)
    query = camera_effects(with_object, 2.0, 2, seed + 2)
    clean = camera_effects(reference, 2.0, 2, seed + 2)
    return ExamplePair(reference, query, clean, np.roll(mask, (2, 2), axis=(0, 1)))
