"""Local evidence: each query pixel against the reference's own neighbourhood.

The cross score compares a pixel with the colour distribution of its whole grid cell. A cell
over station surface holds bright panels, dark shadow and black space, so a thin cable, a
small part or a dark object whose colour occurs *somewhere* in its cell lies inside that
distribution. What the reference says about the pixel's own place is sharper: the colours
within a pixel or two of it. Two cues read it, after the colour transfer (the query in the
reference's colours, so a pixel the reference predicts equals its reference colour). Both
work on whole 8-bit levels (the transferred query is uint8) through per-cell tables.

**Colour cue** (:func:`colour_evidence`). The reference is brought to the query's size
(nearest neighbour) and, per channel, its smallest and largest value within ``radius``
pixels (a square of side ``2 radius + 1``, clipped at the image's border) bound an envelope.
A query pixel's distance is its largest per-channel excess beyond that envelope (the
Chebyshev distance to the box)::

    e_c = max(0, q_c - high_c) + max(0, low_c - q_c),   d = max(e_r, e_g, e_b)

A reference edge that a pose error moves by up to ``radius`` pixels, and a query pixel that
mixes the two sides of an edge (area averaging), lie inside the envelope and cost nothing.
The distance is divided by the cell's robust noise scale,
``sigma = max(sqrt(abs_floor), 1.4826 * m)`` with ``m`` the cell's (lower) median of ``d``
(the floor is the cross score's noise floor; the median reads what noise and texture give
everywhere in the cell), and only a departure beyond :data:`NOISE_SIGMAS` such scales
counts: the evidence is ``(d / sigma)^2`` where ``d > NOISE_SIGMAS * sigma`` and 0
elsewhere, in the units of a squared Mahalanobis distance, those of the cross score.

**Dark cue** (:func:`dark_evidence`), for dark objects: the query is darker than anything
the reference shows nearby, and what the reference shows there is *lit* surface. With ``Y``
the luma (OpenCV's integer BT.601 grey), ``Y_min`` the reference's smallest luma within
``radius`` and ``F`` :data:`DARK_FLOOR`, the share of that surface's light the query lacks,

    rho = round(255 * (Y_min - Y_q) / (Y_min + F)) / 255
          where Y_min > SPACE_LEVEL and Y_min - Y_q > NOISE_SIGMAS * sqrt(abs_floor), else 0

is a ratio, so a shading or exposure difference (a module 30 % darker) weighs little against
an object that hides the surface behind it (a tenth of its brightness). Where the reference
shows space (``Y_min`` at most :data:`SPACE_LEVEL`) darkness is no evidence at all: an
object as dark as space in front of space cannot be seen, and this cue does not pretend to.
The evidence is ``max(0, rho - median)``, the median being the cell's (lower) median of
``rho`` over its lit pixels, so a cell darker than its reference throughout (the query's own
shading) gives none.

:func:`combine` merges the cues with the cross score: a pixel with evidence (always positive)
takes the larger of the two, a pixel without keeps its cross score, so pixels without local
evidence keep their order (the negative band of the ranking map included).
"""

from __future__ import annotations

import cv2
import numpy as np

from allo_mrad_ros.detector.grid import cell_index_map
from allo_mrad_ros.detector.images import SPACE_LEVEL, eight_bit, reference_at
from allo_mrad_ros.detector.reference_cache import ReferenceCache, derived, read_only_cache

__all__ = [
    "DARK_FLOOR",
    "NOISE_SIGMAS",
    "SPACE_LEVEL",
    "colour_evidence",
    "combine",
    "dark_evidence",
]

NOISE_SIGMAS = 3.0
"""Robust standard deviations of a cell's departures that noise and texture may reach."""

DARK_FLOOR = 8.0
"""Luminance (8-bit levels) added to the dark cue's denominator, so a dim surface's share is
not inflated by its noise."""

_MAD_SCALE = 1.4826  # a normal distribution's SD over its median absolute deviation
_LEVELS = 256


def _window(radius: int) -> np.ndarray:
    return np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)


def _envelope(reference: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray]:
    # Per-channel min and max over the square; OpenCV's default border leaves pixels outside
    # the image out of both.
    if radius == 0:
        return reference, reference
    window = _window(radius)
    return cv2.erode(reference, window), cv2.dilate(reference, window)


@read_only_cache(maxsize=8)
def _cell_keys(height: int, width: int, grid: int, stride: int) -> np.ndarray:
    # Each pixel's cell index times ``stride``: adding a value below it gives its (cell,
    # value) bin.
    return (cell_index_map(height, width, grid) * stride).astype(np.int32)


def _cell_medians(keys: np.ndarray, cells: int, stride: int) -> np.ndarray:
    """Per cell, the lower median of the 8-bit values binned in ``keys`` (cell * stride +
    value; values of 256 and above are left out); 0 for a cell with no value."""
    counts = np.bincount(keys.ravel(), minlength=cells * stride).reshape(cells, stride)
    cumulative = np.cumsum(counts[:, :_LEVELS], axis=1)
    half = (cumulative[:, -1:] + 1) // 2
    return np.count_nonzero(cumulative < half, axis=1)


def colour_evidence(
    query: np.ndarray,
    reference: np.ndarray,
    grid: int,
    radius: int,
    abs_floor: float,
    cache: ReferenceCache | None = None,
    *,
    weight: float = 1.0,
    empty: float = 0.0,
) -> np.ndarray:
    """The colour cue (see module): squared robust z of the query's departure from the
    reference's local colour envelope, 0 within :data:`NOISE_SIGMAS`.

    Parameters
    ----------
    query : numpy.ndarray
        H x W x 3 validated image (after the colour transfer: uint8; others are rounded to
        8-bit levels).
    reference : numpy.ndarray
        The reference, same aspect ratio, any resolution (resized to the query's by nearest
        neighbour).
    grid : int
        Cells per side, as the cross score's.
    radius : int
        Half side of the neighbourhood square, query pixels (0: the pixel alone).
    abs_floor : float
        Smallest squared noise scale, 8-bit levels squared (the cross score's floor).
    cache : ReferenceCache, optional
        Keeps the resized reference and its envelope while the reference is reused.
    weight : float
        Factor applied to the evidence (> 0).
    empty : float
        The value where there is no evidence (``-inf`` lets :func:`combine` take the larger
        of score and evidence in one step).

    Returns
    -------
    numpy.ndarray
        H x W float32, finite and > 0 where there is evidence, ``empty`` elsewhere (everywhere
        for identical images, where the query lies within its envelope).
    """
    height, width = query.shape[:2]
    near = reference_at(reference, (height, width), cache)
    low, high = derived(
        cache, reference, ("envelope", height, width, radius), lambda: _envelope(near, radius)
    )
    values = eight_bit(query)
    # Saturating uint8 arithmetic: only one of the two is non-zero per channel.
    excess = cv2.add(cv2.subtract(values, high), cv2.subtract(low, values))
    distance = np.maximum(np.maximum(excess[..., 0], excess[..., 1]), excess[..., 2])
    keys = _cell_keys(height, width, grid, _LEVELS) + distance
    median = _cell_medians(keys, grid * grid, _LEVELS)
    sigma = np.maximum(np.sqrt(abs_floor), _MAD_SCALE * median)[:, None]
    levels = np.arange(_LEVELS, dtype=np.float64)[None, :]
    table = np.where(levels > NOISE_SIGMAS * sigma, weight * (levels / sigma) ** 2, empty)
    return np.take(table.astype(np.float32).ravel(), keys)


_SPACE = _LEVELS  # the dark cue's value where the reference nearby shows space
_DARK_STRIDE = _LEVELS + 1


@read_only_cache(maxsize=8)
def _hidden_share(abs_floor: float) -> np.ndarray:
    # rho in 8-bit levels for every (Y_min, Y_q) pair, flat: Y_min * 256 + Y_q; _SPACE where
    # Y_min is space, so the cell medians can leave those pixels out.
    lowest = np.arange(_LEVELS, dtype=np.float64)[:, None]
    query = np.arange(_LEVELS, dtype=np.float64)[None, :]
    hidden = lowest - query
    share = np.rint(255.0 * hidden / (lowest + DARK_FLOOR))
    share = np.where(hidden > NOISE_SIGMAS * np.sqrt(abs_floor), share, 0.0)
    return np.where(lowest > SPACE_LEVEL, share, _SPACE).astype(np.int32).ravel()


def dark_evidence(
    query: np.ndarray,
    reference: np.ndarray,
    grid: int,
    radius: int,
    abs_floor: float,
    cache: ReferenceCache | None = None,
    *,
    weight: float = 1.0,
    empty: float = 0.0,
) -> np.ndarray:
    """The dark cue (see module): the share of the darkest *lit* reference luma within
    ``radius`` that the query lacks, beyond its cell's median, times ``weight``.

    Parameters as :func:`colour_evidence`; ``abs_floor`` sets the smallest luma difference
    that counts (:data:`NOISE_SIGMAS` noise scales).

    Returns
    -------
    numpy.ndarray
        H x W float32: ``weight * evidence``, evidence in (0, 1), where there is evidence;
        ``empty`` where the reference nearby shows space, where the query is no darker than
        the reference nearby by more than that, and everywhere for identical images.
    """
    height, width = query.shape[:2]

    near = reference_at(reference, (height, width), cache)

    def darkest() -> np.ndarray:
        grey = cv2.cvtColor(near, cv2.COLOR_RGB2GRAY)
        return grey if radius == 0 else cv2.erode(grey, _window(radius))

    lowest = derived(cache, reference, ("darkest", height, width, radius), darkest)
    grey = cv2.cvtColor(eight_bit(query), cv2.COLOR_RGB2GRAY)
    pairs = lowest.astype(np.int32) * _LEVELS + grey
    cells = grid * grid
    keys = _cell_keys(height, width, grid, _DARK_STRIDE) + np.take(
        _hidden_share(float(abs_floor)), pairs
    )
    median = _cell_medians(keys, cells, _DARK_STRIDE)[:, None]
    levels = np.arange(_DARK_STRIDE)[None, :]
    excess = levels - median
    table = np.where((excess > 0) & (levels < _SPACE), weight * excess / 255.0, empty)
    return np.take(table.astype(np.float32).ravel(), keys)


def combine(raw: np.ndarray, evidence: np.ndarray) -> np.ndarray:
    """The cross score with local ``evidence`` (raw-score units, ``-inf`` where there is
    none, as the cues give it with ``empty=-inf``): the larger of the two, so a pixel
    without evidence keeps its cross score, negative or not (a new float32 array)."""
    return cv2.max(raw, evidence)
