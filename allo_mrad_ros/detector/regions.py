"""Stages 4-5: seeds (mean-shift modes), region growing, and the grown regions as records.

:func:`extract_regions` labels the grown mask once, with the connectivity that grew it, and
describes each region (:class:`Region`); every consumer (the node's ``~/result``,
``~/regions`` and ``~/detections``, a user of :func:`~allo_mrad_ros.detector.detect`) reads
those records instead of labelling the mask again.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from allo_mrad_ros.errors import BackendError

_FILL_VALUE = 255

PEAK_TABLE = Path(__file__).resolve().parent.parent / "data" / "region_peaks_normal.json"
"""The shipped calibration table (installed as package data beside the detector)."""


class RegionTableError(BackendError):
    """The calibration table of region peaks shipped with the package is missing or
    malformed (an installation fault, not a user input)."""


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


Box = tuple[int, int, int, int]
"""``(x, y, width, height)`` in pixels."""


@dataclass(frozen=True)
class Region:
    """One connected region of a detection mask: where it is and how strong its evidence.

    Attributes
    ----------
    box : tuple of int
        ``(x, y, width, height)`` of the region's bounding box in the image's pixels (the
        query's resolution, that of ``DetectionResult.mask``).
    area : int
        The region's pixels in the image.
    centroid : tuple of float
        ``(x, y)``, the mean of its pixels' coordinates in the image (a pixel's centre at
        integer coordinates, as OpenCV's centroids).
    work_box : tuple of int
        ``box`` at the processing resolution (``DetectionResult.work_mask``).
    work_area : int
        The region's pixels at the processing resolution.
    peak_score : float
        Largest value, 0..255, over the region's pixels of the evidence map: the map the
        mask was grown on (MRAD's blurred score, the baselines' scaled score), at the
        processing resolution. It does not depend on ``pixel_score``.
    mean_score : float
        Mean of the evidence map over the region's pixels, 0..255.
    score : float
        In [0, 1]: the fraction of the regions the detector grew on normal (anomaly-free)
        validation frames whose peak is below this region's ``peak_score`` (ties count
        half), read from the shipped table (:func:`region_score`). 0.9 means the region's
        peak exceeds 90 % of those regions' peaks. A non-decreasing function of
        ``peak_score``, calibrated for MRAD with the default parameters.
    """

    box: Box
    area: int
    centroid: tuple[float, float]
    work_box: Box
    work_area: int
    peak_score: float
    mean_score: float
    score: float


@functools.cache
def normal_peaks(path: Path = PEAK_TABLE) -> np.ndarray:
    """The sorted peaks (0..255) of the table at ``path``, read once per path.

    Raises
    ------
    RegionTableError
        If the file cannot be read, or its ``peaks`` are empty, not finite or not sorted.
    """
    try:
        table = json.loads(Path(path).read_text(encoding="utf-8"))
        peaks = np.asarray(table["peaks"], dtype=np.float64)
    except (OSError, ValueError, TypeError, KeyError) as error:
        raise RegionTableError(f"{path}: cannot read the region peak table: {error}") from None
    if peaks.ndim != 1 or peaks.size == 0:
        raise RegionTableError(f"{path}: 'peaks' must be a non-empty list of numbers")
    if not np.all(np.isfinite(peaks)) or np.any(np.diff(peaks) < 0):
        raise RegionTableError(f"{path}: 'peaks' must be finite and sorted ascending")
    peaks.setflags(write=False)
    return peaks


def region_score(peak_score: float, peaks: np.ndarray | None = None) -> float:
    """A region's score in [0, 1]: where its peak evidence ranks among normal regions' peaks.

    ``(number of peaks < p + 0.5 * number equal to p) / N`` for ``N`` sorted ``peaks`` (the
    shipped table of :func:`normal_peaks` when None), the mid-rank empirical distribution
    function: non-decreasing in ``p``, 0 below every peak and 1 above every peak.
    """
    table = normal_peaks() if peaks is None else peaks
    value = float(peak_score)
    below = int(np.searchsorted(table, value, side="left"))
    equal = int(np.searchsorted(table, value, side="right")) - below
    return (below + 0.5 * equal) / len(table)


def extract_regions(
    mask: np.ndarray,
    evidence: np.ndarray,
    shape: tuple[int, int],
    connectivity: int,
) -> tuple[Region, ...]:
    """The connected regions of a grown mask, in the raster order of their first pixel.

    Parameters
    ----------
    mask : numpy.ndarray
        h x w uint8 mask (non-zero = anomalous) at the processing resolution.
    evidence : numpy.ndarray
        h x w score map, 0..255, the mask was grown on.
    shape : tuple of int
        ``(height, width)`` of the image the mask is enlarged to by nearest neighbour (as
        ``cv2.resize`` with ``INTER_NEAREST``), at least ``mask``'s size.
    connectivity : {4, 8}
        The neighbourhood that grew the mask.

    Returns
    -------
    tuple of Region

    Raises
    ------
    ValueError
        If the shapes disagree or ``connectivity`` is not 4 or 8.
    """
    if connectivity not in (4, 8):
        raise ValueError(f"connectivity must be 4 or 8, got {connectivity!r}")
    if mask.ndim != 2 or evidence.shape != mask.shape:
        raise ValueError(f"mask {mask.shape} and evidence {evidence.shape} must be one 2-D size")
    if len(shape) != 2 or shape[0] < mask.shape[0] or shape[1] < mask.shape[1]:
        raise ValueError(f"image size {tuple(shape)} is smaller than the mask's {mask.shape}")
    foreground = mask if mask.dtype == np.uint8 else (mask != 0).astype(np.uint8)
    # Labelling the mask's bounding box only gives the same regions: at 1080p labelling the
    # whole mask costs about 20 ms, and an anomaly covers a small part of it.
    left, top, width, height = cv2.boundingRect(foreground)
    if width == 0 or height == 0:
        return ()
    box = foreground[top : top + height, left : left + width]
    count, labels, stats, _ = cv2.connectedComponentsWithStats(box, connectivity=connectivity)
    rows, cols = np.nonzero(labels)  # raster order
    label = labels[rows, cols]
    values = evidence[top : top + height, left : left + width][rows, cols].astype(np.float64)
    peak = np.full(count, -np.inf)
    np.maximum.at(peak, label, values)
    total = np.bincount(label, weights=values, minlength=count)
    rows += top
    cols += left
    # Each processing pixel becomes a block of image pixels; per axis, a block's first
    # pixel, its size and the sum of its coordinates.
    row_start, row_size, row_sum = _blocks(mask.shape[0], shape[0])
    col_start, col_size, col_sum = _blocks(mask.shape[1], shape[1])
    block_area = (row_size[rows] * col_size[cols]).astype(np.float64)
    area = np.bincount(label, weights=block_area, minlength=count)
    x_sum = np.bincount(label, weights=row_size[rows] * col_sum[cols], minlength=count)
    y_sum = np.bincount(label, weights=col_size[cols] * row_sum[rows], minlength=count)
    # cv2 may number the regions in another order (its parallel labelling); the order of
    # their first pixels is the one a reader of the mask expects.
    _, first = np.unique(label, return_index=True)
    regions = []
    for index in label[np.sort(first)]:
        x, y, w, h, work_area = (int(v) for v in stats[index, :5])
        x += left
        y += top
        x0, y0 = int(col_start[x]), int(row_start[y])
        x1 = int(col_start[x + w - 1] + col_size[x + w - 1])
        y1 = int(row_start[y + h - 1] + row_size[y + h - 1])
        pixels = float(area[index])
        regions.append(
            Region(
                box=(x0, y0, x1 - x0, y1 - y0),
                area=round(pixels),
                centroid=(float(x_sum[index] / pixels), float(y_sum[index] / pixels)),
                work_box=(x, y, w, h),
                work_area=work_area,
                peak_score=float(peak[index]),
                mean_score=float(total[index] / work_area),
                score=region_score(peak[index]),
            )
        )
    return tuple(regions)


def _blocks(size: int, image_size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel of an axis of ``size`` enlarged to ``image_size`` by nearest neighbour: the
    first image pixel of its block, the block's size and the sum of the block's coordinates.

    The source of each image pixel is read from OpenCV's own nearest-neighbour resize of an
    index ramp, so the blocks follow the enlargement the mask goes through exactly.
    """
    if size == image_size:
        index = np.arange(size, dtype=np.float64)
        return index.astype(np.int64), np.ones(size, np.int64), index
    ramp = np.arange(size, dtype=np.float32).reshape(1, size)
    source = cv2.resize(ramp, (image_size, 1), interpolation=cv2.INTER_NEAREST)[0]
    source = source.astype(np.int64)
    start = np.searchsorted(source, np.arange(size), side="left")
    end = np.searchsorted(source, np.arange(size), side="right")
    block = end - start
    # Sum of start..end-1: a block of n pixels from s sums to n * (2 s + n - 1) / 2.
    return start, block, block * (2 * start + block - 1) / 2.0
