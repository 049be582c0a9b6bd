"""Stages 4-5: seeds (mean-shift modes) and region growing."""

from __future__ import annotations

import math

import cv2
import numpy as np

_FILL_VALUE = 255


def seed_window(sigma: float) -> int:
    """Side of the local-maximum window for a blur of ``sigma`` px: ``2*ceil(sigma)+1``, >= 3."""
    return max(3, 2 * math.ceil(sigma) + 1)


def find_seeds(blurred: np.ndarray, min_score: float, window: int) -> np.ndarray:
    """Return region-growing seeds: the modes of the blurred score density.

    With a Gaussian kernel of the blur's bandwidth, the modes mean shift climbs to are the
    local maxima of the blurred map, found here by comparing the map with its grey-scale
    dilation. A plateau of equal maxima yields one seed (its first pixel in raster order).

    Parameters
    ----------
    blurred : numpy.ndarray
        H x W float32 blurred score map.
    min_score : float
        Seeds must score at least this and more than zero.
    window : int
        Side of the square neighbourhood a seed must dominate.

    Returns
    -------
    numpy.ndarray
        (N, 2) int array of (row, col), sorted by descending score, then raster order.
    """
    kernel = np.ones((window, window), dtype=np.uint8)
    dilated = cv2.dilate(blurred, kernel, borderType=cv2.BORDER_REPLICATE)
    floor = max(float(min_score), float(np.finfo(np.float32).tiny))
    peaks = cv2.bitwise_and(
        cv2.compare(blurred, dilated, cv2.CMP_GE), cv2.compare(blurred, floor, cv2.CMP_GE)
    )
    points = cv2.findNonZero(peaks)
    if points is None:
        return np.empty((0, 2), dtype=np.int64)
    _, labels = cv2.connectedComponents(peaks, connectivity=8)
    points = points.reshape(-1, 2)  # OpenCV 4 gives (N, 1, 2), OpenCV 5 (N, 2)
    cols, rows = points[:, 0], points[:, 1]
    # findNonZero lists pixels in raster order, so the first hit per label is its first pixel.
    _, first = np.unique(labels[rows, cols], return_index=True)
    rows, cols = rows[first].astype(np.int64), cols[first].astype(np.int64)
    order = np.lexsort((cols, rows, -blurred[rows, cols]))
    return np.column_stack([rows[order], cols[order]])


def grow_regions(
    blurred: np.ndarray,
    seeds: np.ndarray,
    tolerance: float,
    min_score: float,
    connectivity: int = 8,
) -> np.ndarray:
    """Grow a region from every seed and return their union as a 0/255 mask.

    A neighbour joins a seed's region when its blurred score lies within ``tolerance`` of
    the seed's score (a seeded flood fill with a fixed range) and is at least ``min_score``
    (so a weak seed cannot flood the empty background).

    Returns
    -------
    numpy.ndarray
        H x W uint8 mask with 0 and 255.
    """
    height, width = blurred.shape
    fill_mask = np.zeros((height + 2, width + 2), dtype=np.uint8)
    if len(seeds) == 0:
        return fill_mask[1:-1, 1:-1].copy()
    # Non-zero mask pixels stop the fill: below-threshold scores are a barrier.
    below = cv2.compare(blurred, float(min_score), cv2.CMP_LT)
    np.bitwise_and(below, 1, out=fill_mask[1:-1, 1:-1])
    flags = connectivity | cv2.FLOODFILL_FIXED_RANGE | cv2.FLOODFILL_MASK_ONLY | (_FILL_VALUE << 8)
    image = np.ascontiguousarray(blurred, dtype=np.float32)
    for row, col in seeds:
        if fill_mask[row + 1, col + 1]:
            continue
        cv2.floodFill(image, fill_mask, (int(col), int(row)), 0, tolerance, tolerance, flags)
    return cv2.compare(fill_mask[1:-1, 1:-1], _FILL_VALUE, cv2.CMP_EQ)


def grow_hysteresis(
    blurred: np.ndarray, low: float, high: float, connectivity: int = 8
) -> np.ndarray:
    """Hysteresis thresholding: the regions at or above ``low`` that reach ``high``.

    Every connected region of ``blurred >= low`` (``low`` > 0) that holds at least one pixel
    ``>= high`` is kept whole, so a small or thin object whose peak is modest is kept with
    its full extent, and a strong object grows down to ``low`` rather than to a fixed range
    below its peak.

    Returns
    -------
    numpy.ndarray
        H x W uint8 mask with 0 and 255.
    """
    floor = max(float(low), float(np.finfo(np.float32).tiny))
    candidates = cv2.compare(blurred, floor, cv2.CMP_GE)
    count, labels = cv2.connectedComponents(candidates, connectivity=connectivity)
    if count <= 1:
        return np.zeros(blurred.shape, dtype=np.uint8)
    strong = labels[blurred >= max(float(high), floor)]
    keep = np.zeros(count, dtype=np.uint8)
    keep[strong] = _FILL_VALUE
    keep[0] = 0
    return keep[labels]
