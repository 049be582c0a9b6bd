"""Stage 1a': photometric alignment of the reference's cell statistics to the query.

A camera never matches a render's exposure, tone curve, white balance or light fall-off.
Within one cell such a difference is close to a per-channel gain and offset, so each cell's
reference colours are mapped onto the query's by ``y = gain * x + offset`` fitted to their
quantile-quantile plot: the query's and the reference's per-channel quantiles (10 % .. 90 %)
are paired and a Theil-Sen line (median of pairwise slopes) is fitted through them. Quantiles
ignore where pixels are, so the fit needs no pixel alignment (the reference may be rendered
at another resolution or pose), and the median slope ignores the few quantiles an anomaly
moves: an object covering less than about a quarter of a cell does not bend the fit. A
larger object can steepen a cell's slope, so each cell takes the median gain of its 3 x 3
neighbourhood of cells (the photometric difference is smooth across the frame, objects are
local) and fits its offset under that gain.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.ndimage import median_filter

from allo_mrad_ros.detector.grid import cell_index_map, cell_slices
from allo_mrad_ros.detector.images import area_downscale, to_float32
from allo_mrad_ros.detector.reference_cache import ReferenceCache, derived, read_only_cache
from allo_mrad_ros.errors import InvalidInput

QUANTILES = np.linspace(0.1, 0.9, 9)
SATURATED = 250.0
# A cell and its four edge neighbours (one channel at a time).
_CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], dtype=bool)[:, :, None]
# Below this spread (8-bit units) a cell's quantiles carry no slope: such a cell takes the
# frame's median gain of the cells that have one (an exposure change is mostly global), or 1.
_MIN_SPREAD = 4.0


class PhotometricError(InvalidInput):
    """The photometric fit cannot run on these inputs."""


def cell_quantiles(image: np.ndarray, grid: int) -> np.ndarray:
    """Per-cell, per-channel quantiles :data:`QUANTILES` of an image, on the 0..255 scale.

    Linear interpolation between order statistics, as ``numpy.quantile``'s default. An
    8-bit image goes through per-cell histograms (this runs every frame); other dtypes
    through one sort per cell.

    Returns
    -------
    numpy.ndarray
        (G*G, 3, len(QUANTILES)) float64.
    """
    if image.dtype == np.uint8:
        return _quantiles_uint8(image, grid)
    pixels = to_float32(image)
    slices = cell_slices(pixels.shape[0], pixels.shape[1], grid)
    out = np.empty((len(slices), 3, QUANTILES.size))
    for index, cell in enumerate(slices):
        values = np.sort(pixels[cell].reshape(-1, 3), axis=0)
        position = QUANTILES * (values.shape[0] - 1)
        low = np.floor(position).astype(np.intp)
        high = np.minimum(low + 1, values.shape[0] - 1)
        weight = (position - low)[:, None]
        below, above = values[low].astype(np.float64), values[high].astype(np.float64)
        out[index] = (below + weight * (above - below)).T
    return out


def _quantiles_uint8(image: np.ndarray, grid: int) -> np.ndarray:
    # One histogram per (cell, channel) from a single bincount, then each quantile's order
    # statistics by one sorted search over all histograms' cumulative counts.
    histograms = grid * grid * 3
    counts = np.bincount(
        (_histogram_base(image.shape[0], image.shape[1], grid) + image).ravel(),
        minlength=histograms * 256,
    )
    cdf = np.cumsum(counts.reshape(histograms, 256), axis=1)
    total = cdf[:, -1:]
    position = QUANTILES[None, :] * (total - 1)
    low = np.floor(position)
    high = np.minimum(low + 1, total - 1)
    # The value of order statistic r is the number of levels whose cdf is <= r: each
    # histogram's cdf is lifted above the previous one's so one search serves them all.
    lift = np.arange(histograms)[:, None] * (int(total.max()) + 1)
    lifted = (cdf + lift).ravel()
    level_base = np.arange(histograms)[:, None] * 256
    below = np.searchsorted(lifted, (low + lift).astype(np.int64), side="right") - level_base
    above = np.searchsorted(lifted, (high + lift).astype(np.int64), side="right") - level_base
    return (below + (position - low) * (above - below)).reshape(grid * grid, 3, QUANTILES.size)


@read_only_cache(maxsize=8)
def _histogram_base(height: int, width: int, grid: int) -> np.ndarray:
    # Bin offset of each pixel's (cell, channel) histogram; the pixel value is added to it.
    cells = cell_index_map(height, width, grid)
    return (cells[:, :, None] * 768 + 256 * np.arange(3)).astype(np.intp)


def fit_cell_affine(
    query: np.ndarray,
    reference: np.ndarray,
    grid: int,
    max_gain: float,
    quantiles: Callable[[np.ndarray, int], np.ndarray] | None = None,
    cache: ReferenceCache | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Fit ``query ~ gain * reference + offset`` per cell and channel.

    The larger image is first resized (area averaging) to the smaller one's size, so both
    quantile sets describe the same level of detail.

    Parameters
    ----------
    query, reference : numpy.ndarray
        Validated H x W x 3 images with the same aspect ratio.
    grid : int
        Cells per side.
    max_gain : float
        Gains are clipped to ``[1 / max_gain, max_gain]`` (>= 1).
    quantiles : callable, optional
        ``(image, grid) -> quantiles`` as :func:`cell_quantiles` (the default), e.g. an
        array backend's.
    cache : ReferenceCache, optional
        Where the reference's quantiles are kept while it is reused.

    Returns
    -------
    gain, offset : numpy.ndarray
        (G*G, 3) float64 each; the offset is in 8-bit units.
    """
    if not max_gain >= 1.0:
        raise PhotometricError(f"max_gain must be at least 1, got {max_gain!r}")
    query, reference = _same_size(query, reference)
    quantiles = quantiles or cell_quantiles
    q = quantiles(query, grid)
    r = derived(
        cache, reference, ("cell_quantiles", quantiles, grid), lambda: quantiles(reference, grid)
    )
    i, j = np.triu_indices(QUANTILES.size, k=1)
    dq, dr = q[..., j] - q[..., i], r[..., j] - r[..., i]
    # Pairs with a flat reference carry no slope; they are left out of the median.
    valid = dr > 0.25
    slopes = np.where(valid, dq / np.where(valid, dr, 1.0), np.nan)
    spread = r[..., -1] - r[..., 0]
    has_slope = (spread >= _MIN_SPREAD) & valid.any(axis=-1)
    gain = np.clip(_median_of_valid(slopes, valid), 1.0 / max_gain, max_gain)
    frame_gain = np.ones(3)
    for channel in range(3):
        if has_slope[:, channel].any():
            frame_gain[channel] = np.median(gain[has_slope[:, channel], channel])
    gain = np.where(has_slope, gain, frame_gain[None, :])
    offset = np.median(q - gain[..., None] * r, axis=-1)
    return _neighbourhood_median(gain, grid), _neighbourhood_median(offset, grid)


def _neighbourhood_median(values: np.ndarray, grid: int) -> np.ndarray:
    # A camera's gain varies smoothly across the frame; an object is local. The median
    # over each cell's 3 x 3 neighbourhood of cells keeps the first and drops a cell whose
    # slope an object bent; the offset is then refitted in the cell itself, so a gain that
    # changes faster than the neighbourhood (vignetting in a corner) ends up in the offset.
    if grid < 2:
        return values
    cells = values.reshape(grid, grid, -1)
    return median_filter(cells, footprint=_CROSS, mode="nearest").reshape(values.shape)


def saturation_variance(reference: np.ndarray, grid: int, max_gain: float) -> np.ndarray:
    """Extra covariance per cell for clipped (saturated) reference pixels.

    A saturated render pixel only says "at least white": under a camera's gain down to
    ``1 / max_gain`` and its vignetting the same surface may show anywhere from its clipped
    colour ``c`` down to ``c / max_gain``, so the uncertainty lies along ``c``, not across
    colours. Each cell gains ``fraction * (range / 2)^2 * u u^T`` with ``u = c / 255`` the
    mean colour of its saturated pixels (any channel >= 250), ``fraction`` their share and
    ``range = 255 * (1 - 1 / max_gain)``.

    Returns
    -------
    numpy.ndarray
        (G*G, 3, 3) float64 covariances in 8-bit units squared.
    """
    pixels = to_float32(reference)
    # NumPy's max over a length-3 last axis is ~50x slower than two elementwise maxima.
    brightest = np.maximum(np.maximum(pixels[:, :, 0], pixels[:, :, 1]), pixels[:, :, 2])
    saturated = brightest >= SATURATED
    cells = grid * grid
    out = np.zeros((cells, 3, 3))
    if not saturated.any():
        return out
    index = cell_index_map(pixels.shape[0], pixels.shape[1], grid)
    which = index[saturated]
    count = np.bincount(which, minlength=cells)
    clipped_pixels = pixels[saturated].astype(np.float64)
    sums = np.stack(
        [np.bincount(which, weights=clipped_pixels[:, c], minlength=cells) for c in range(3)],
        axis=1,
    )
    size = np.bincount(index.ravel(), minlength=cells)
    has = count > 0
    colour = sums[has] / count[has, None] / 255.0
    half_range = 0.5 * 255.0 * (1.0 - 1.0 / max_gain)
    share = (count[has] / size[has]) * half_range**2
    out[has] = share[:, None, None] * colour[:, :, None] * colour[:, None, :]
    return out


def _median_of_valid(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    # nanmedian's general path costs more than the rest of the fit; NaNs sort last.
    ordered = np.sort(np.where(valid, values, np.nan), axis=-1)
    count = valid.sum(axis=-1, keepdims=True)
    low = np.take_along_axis(ordered, np.maximum(count - 1, 0) // 2, axis=-1)
    high = np.take_along_axis(ordered, np.maximum(count // 2, 0), axis=-1)
    median = 0.5 * (low + high)[..., 0]
    return np.where(count[..., 0] > 0, median, 1.0)


def _same_size(query: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    hq, wq = query.shape[:2]
    hr, wr = reference.shape[:2]
    if hq * wq > hr * wr:
        return area_downscale(query, (wr, hr)), reference
    if hr * wr > hq * wq:
        return query, area_downscale(reference, (wq, hq))
    return query, reference
