"""Stage 1b: the cross RXD score (and the plain RX score) per grid cell.

Per cell, ``(x-mu0)^T P0 (x-mu0) - (x-mu1)^T P1 (x-mu1)`` is one quadratic form in ``x``.
It is evaluated around the query mean in the eigenbasis of ``A = P0 - P1``:
``sum_i l_i y_i^2 + m . y + k`` with ``y = V^T (x - mu1)``. The coefficients are computed
in float64 (so equal statistics cancel exactly to ``A = 0``), the per-pixel evaluation is
two OpenCV colour transforms in float32.
"""

from __future__ import annotations

import cv2
import numpy as np

from allo_mrad_ros.detector.grid import cell_slices
from allo_mrad_ros.detector.images import to_float32
from allo_mrad_ros.detector.photometric import fit_cell_affine, saturation_variance
from allo_mrad_ros.detector.statistics import cell_statistics, regularised_precision


def cross_score(
    query: np.ndarray,
    reference: np.ndarray,
    grid: int,
    abs_floor: float,
    rel_floor: float,
    photometric: str = "none",
    max_gain: float = 2.0,
) -> np.ndarray:
    """Return the cross RXD score of every query pixel against its reference cell.

    Parameters
    ----------
    query, reference : numpy.ndarray
        Validated H x W x 3 images with the same aspect ratio (any resolutions).
    grid : int
        Cells per side.
    abs_floor, rel_floor : float
        Covariance regularisation (see :func:`regularised_precision`).
    photometric : {"none", "cell_affine"}
        ``cell_affine`` first maps each reference cell's statistics through the gain and
        offset fitted by :func:`~allo_mrad_ros.detector.photometric.fit_cell_affine`.
    max_gain : float
        Gain limit of the ``cell_affine`` fit.

    Returns
    -------
    numpy.ndarray
        H x W float32 raw score of the query, finite.
    """
    ref_stats = cell_statistics(reference, grid)
    query_stats = cell_statistics(query, grid)
    if photometric == "none":
        ref_precision = regularised_precision(ref_stats.cov, abs_floor, rel_floor)
        query_precision = regularised_precision(query_stats.cov, abs_floor, rel_floor)
        ref_mean = ref_stats.mean
    elif photometric == "cell_affine":
        # Score in the reference's photometric units (x_ref = (x - offset) / gain), so the
        # regularisation floors mean the same whatever the query's exposure: a darker
        # query does not hide its anomalies under a floor sized for the render.
        gain, offset = fit_cell_affine(query, reference, grid, max_gain)
        ref_mean = gain * ref_stats.mean + offset
        inverse = 1.0 / gain
        in_ref_units = query_stats.cov * inverse[:, :, None] * inverse[:, None, :]
        # Both models are widened where the reference is saturated, so identical images
        # still cancel exactly.
        widening = saturation_variance(reference, grid, max_gain)
        ref_precision = _to_query_units(
            regularised_precision(ref_stats.cov + widening, abs_floor, rel_floor),
            inverse,
        )
        query_precision = _to_query_units(
            regularised_precision(in_ref_units + widening, abs_floor, rel_floor),
            inverse,
        )
    else:
        raise ValueError(f"photometric must be 'none' or 'cell_affine', got {photometric!r}")
    return _evaluate(
        to_float32(query),
        grid,
        ref_mean,
        ref_precision,
        query_stats.mean,
        query_precision,
    )


def _to_query_units(precision: np.ndarray, inverse_gain: np.ndarray) -> np.ndarray:
    # A precision P on x_ref = (x - o) / g is D^-1 P D^-1 on x, D = diag(g).
    return precision * inverse_gain[:, :, None] * inverse_gain[:, None, :]


def rx_score(image: np.ndarray, abs_floor: float, rel_floor: float) -> np.ndarray:
    """Return the global RX score: squared Mahalanobis distance to the image's own model."""
    stats = cell_statistics(image, 1)
    precision = regularised_precision(stats.cov, abs_floor, rel_floor)
    return _evaluate(
        to_float32(image), 1, stats.mean, precision, stats.mean, np.zeros_like(precision)
    )


def quadratic_coefficients(
    mu0: np.ndarray, p0: np.ndarray, mu1: np.ndarray, p1: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Coefficients of ``(x-mu0)^T p0 (x-mu0) - (x-mu1)^T p1 (x-mu1)`` around ``mu1``.

    Returns
    -------
    transform : numpy.ndarray
        3x4 affine map ``x -> y = V^T (x - mu1)``.
    eigenvalues : numpy.ndarray
        (3,) eigenvalues ``l`` of ``A = p0 - p1``.
    linear : numpy.ndarray
        (3,) coefficients ``m`` of ``y``.
    constant : float
        ``k``, the score at ``x = mu1``.
    """
    a = p0 - p1
    a = 0.5 * (a + a.T)
    eigenvalues, vectors = np.linalg.eigh(a)
    delta = mu1 - mu0
    linear = vectors.T @ (2.0 * p0 @ delta)
    constant = float(delta @ p0 @ delta)
    transform = np.hstack([vectors.T, (-vectors.T @ mu1)[:, None]])
    return transform, eigenvalues, linear, constant


def _evaluate(
    image: np.ndarray,
    grid: int,
    mean0: np.ndarray,
    precision0: np.ndarray,
    mean1: np.ndarray,
    precision1: np.ndarray,
) -> np.ndarray:
    height, width = image.shape[:2]
    score = np.empty((height, width), dtype=np.float32)
    for index, cell in enumerate(cell_slices(height, width, grid)):
        transform, eigenvalues, linear, constant = quadratic_coefficients(
            mean0[index], precision0[index], mean1[index], precision1[index]
        )
        if not eigenvalues.any() and not linear.any():
            score[cell] = constant  # identical statistics: no per-pixel work
            continue
        y = cv2.transform(image[cell], transform.astype(np.float32))
        quadratic = cv2.transform(cv2.multiply(y, y), eigenvalues[None, :].astype(np.float32))
        affine = np.append(linear, constant)[None, :].astype(np.float32)
        np.add(quadratic, cv2.transform(y, affine), out=score[cell])
    if not cv2.checkRange(score):
        # Only reachable with unregularised, near-singular statistics: saturate, never NaN.
        big = float(np.finfo(np.float32).max)
        np.nan_to_num(score, copy=False, nan=0.0, posinf=big, neginf=-big)
    return score
