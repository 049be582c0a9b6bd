"""Stage 1a: colour statistics per grid cell, and their regularised inverses.

Sums are accumulated exactly (integers) for 8-bit images and in float64 around a per-cell
centre otherwise, so the covariances of flat cells (black sky, grey metal, saturated
glare) come out as exact zeros or tiny values instead of cancellation noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from allo_mrad_ros.detector.grid import cell_edges, cell_slices
from allo_mrad_ros.detector.images import to_float32
from allo_mrad_ros.detector.threads import for_each_block

# Channel products (c, next c): (0,1), (1,2), (2,0) cover the off-diagonal of a 3x3
# covariance; a channel permutation as a colour transform avoids NumPy's fancy-index copy.
_CROSS_A = [0, 1, 2]
_CROSS_B = [1, 2, 0]
_NEXT_CHANNEL = np.eye(3, dtype=np.float32)[_CROSS_B]
# Column sums of up to this many rows of 8-bit squares stay below 2**24.
_EXACT_FLOAT32_ROWS = (1 << 24) // (255 * 255)


@dataclass(frozen=True)
class CellStatistics:
    """Mean and sample covariance (ddof = 1) of the pixels of each cell.

    Attributes
    ----------
    mean : numpy.ndarray
        (G*G, 3) float64, 0..255 scale, cells row-major.
    cov : numpy.ndarray
        (G*G, 3, 3) float64; zero for single-pixel cells.
    count : numpy.ndarray
        (G*G,) int64 pixel counts.
    """

    mean: np.ndarray
    cov: np.ndarray
    count: np.ndarray


def cell_statistics(image: np.ndarray, grid: int) -> CellStatistics:
    """Return the colour mean and covariance of every cell of a validated image.

    Parameters
    ----------
    image : numpy.ndarray
        H x W x 3 image of an accepted dtype (see :func:`check_image`).
    grid : int
        Cells per side.

    Returns
    -------
    CellStatistics
    """
    slices = cell_slices(image.shape[0], image.shape[1], grid)
    if image.dtype == np.uint8:
        return _statistics_uint8(image, grid)
    return _statistics_float(to_float32(image), slices)


def _statistics_uint8(image: np.ndarray, grid: int) -> CellStatistics:
    # Products of 8-bit values are integers below 2**16, exact in float32, and so are their
    # sums while a band holds fewer than 2**24 / 255**2 rows (else they are summed in
    # float64): the covariance is exact up to the final division. Sums run one row of
    # cells at a time (a column sum over the band, then sums over each cell's columns), a
    # few OpenCV calls per band instead of per cell.
    height, width = image.shape[:2]
    row_edges = cell_edges(height, grid)
    col_starts = cell_edges(width, grid)[:-1]
    sums = np.empty((grid, grid, 3))
    squares = np.empty((grid, grid, 3))
    cross = np.empty((grid, grid, 3))

    def accumulate(bands: range) -> None:
        for band in bands:
            pixels = image[row_edges[band] : row_edges[band + 1]].astype(np.float32)
            exact = cv2.CV_32F if pixels.shape[0] < _EXACT_FLOAT32_ROWS else cv2.CV_64F
            for out, values in (
                (sums, pixels),
                (squares, cv2.multiply(pixels, pixels)),
                (cross, cv2.multiply(pixels, cv2.transform(pixels, _NEXT_CHANNEL))),
            ):
                columns = cv2.reduce(values, 0, cv2.REDUCE_SUM, dtype=exact)
                out[band] = np.add.reduceat(
                    columns.reshape(width, 3).astype(np.float64), col_starts, axis=0
                )

    for_each_block(accumulate, grid, min_per_block=1, pixels=height * width)
    n_cells = grid * grid
    rows = np.diff(row_edges)
    cols = np.diff(cell_edges(width, grid))
    count = (rows[:, None] * cols[None, :]).reshape(n_cells).astype(np.int64)
    sums = sums.reshape(n_cells, 3)
    second = np.empty((n_cells, 3, 3))
    diagonal = np.arange(3)
    second[:, diagonal, diagonal] = squares.reshape(n_cells, 3)
    second[:, _CROSS_A, _CROSS_B] = cross.reshape(n_cells, 3)
    second[:, _CROSS_B, _CROSS_A] = cross.reshape(n_cells, 3)
    n = count.astype(np.float64)[:, None]
    outer = sums[:, :, None] * sums[:, None, :]
    cov = (second - outer / n[:, :, None]) / np.maximum(n - 1, 1)[:, :, None]
    return CellStatistics(mean=sums / n, cov=cov, count=count)


def _statistics_float(image: np.ndarray, slices: list[tuple[slice, slice]]) -> CellStatistics:
    n_cells = len(slices)
    mean = np.empty((n_cells, 3))
    cov = np.empty((n_cells, 3, 3))
    count = np.empty(n_cells, dtype=np.int64)
    for index, cell in enumerate(slices):
        pixels = image[cell].reshape(-1, 3)
        n = pixels.shape[0]
        centre = np.array(cv2.mean(image[cell])[:3])
        centred = pixels.astype(np.float64) - centre
        offset = centred.mean(axis=0)
        mean[index] = centre + offset
        cov[index] = (centred.T @ centred - n * np.outer(offset, offset)) / max(n - 1, 1)
        count[index] = n
    return CellStatistics(mean=mean, cov=cov, count=count)


def regularised_precision(cov: np.ndarray, abs_floor: float, rel_floor: float) -> np.ndarray:
    """Invert ``S + lambda * I`` with ``lambda = max(abs_floor, rel_floor * trace(S) / 3)``.

    The inverse goes through a symmetric eigendecomposition; eigenvalues are clamped to a
    tiny positive value so even unregularised singular matrices (``abs_floor = 0`` in
    property tests) give a finite precision.

    Parameters
    ----------
    cov : numpy.ndarray
        (..., 3, 3) covariances.
    abs_floor, rel_floor : float
        Regularisation floors (>= 0).

    Returns
    -------
    numpy.ndarray
        (..., 3, 3) float64 precision matrices.
    """
    cov = np.asarray(cov, dtype=np.float64)
    trace = np.trace(cov, axis1=-2, axis2=-1)
    lam = np.maximum(abs_floor, rel_floor * trace / 3.0)
    regularised = cov + lam[..., None, None] * np.eye(3)
    regularised = 0.5 * (regularised + np.swapaxes(regularised, -1, -2))
    values, vectors = np.linalg.eigh(regularised)
    floor = np.maximum(values.max(axis=-1, keepdims=True), 1.0) * 1e-12
    inverse_values = 1.0 / np.maximum(values, floor)
    return (vectors * inverse_values[..., None, :]) @ np.swapaxes(vectors, -1, -2)
