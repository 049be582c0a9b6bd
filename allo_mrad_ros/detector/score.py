"""Stage 1b: the cross RXD score (and the plain RX score) per grid cell.

Per cell, ``(x-mu0)^T P0 (x-mu0) - (x-mu1)^T P1 (x-mu1)`` is one quadratic form in ``x``.
It is evaluated around the query mean in the eigenbasis of ``A = P0 - P1``:
``sum_i l_i y_i^2 + m . y + k`` with ``y = V^T (x - mu1)``. The coefficients are computed
in float64 (so equal statistics cancel exactly to ``A = 0``), the per-pixel evaluation is
a few OpenCV channel transforms in float32.

:func:`cross_scores` scores one query under several photometric models at once: the cell
statistics and the photometric fit are computed once and every model's per-pixel work is
done while a cell's pixels are in cache.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from allo_mrad_ros.detector.grid import cell_slices
from allo_mrad_ros.detector.images import to_float32
from allo_mrad_ros.detector.photometric import fit_cell_affine, saturation_variance
from allo_mrad_ros.detector.statistics import (
    CellStatistics,
    cell_statistics,
    regularised_precision,
)
from allo_mrad_ros.detector.threads import for_each_block

PHOTOMETRIC_MODELS = ("none", "cell_affine")
# From this absolute floor on a precision's eigenvalues are at most max_gain**2 / floor
# (<= 1e7), so every score is far inside float32's range and the final finiteness check
# over the whole map can be skipped; below it (property tests run unregularised) it runs.
_BOUNDED_FLOOR = 1e-3


@dataclass(frozen=True)
class CellModels:
    """The two Gaussians a cross score compares, per cell.

    Attributes
    ----------
    ref_mean, query_mean : numpy.ndarray
        (G*G, 3) float64 means on the 0..255 scale.
    ref_precision, query_precision : numpy.ndarray
        (G*G, 3, 3) float64 precision matrices.
    """

    ref_mean: np.ndarray
    ref_precision: np.ndarray
    query_mean: np.ndarray
    query_precision: np.ndarray


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

    The one-model form of :func:`cross_scores` (same parameters, ``photometric`` one of
    its models): ``cell_affine`` first maps each reference cell's statistics through the
    gain and offset fitted by :func:`~allo_mrad_ros.detector.photometric.fit_cell_affine`.

    Returns
    -------
    numpy.ndarray
        H x W float32 raw score of the query, finite.
    """
    return cross_scores(query, reference, grid, abs_floor, rel_floor, (photometric,), max_gain)[0]


def cross_scores(
    query: np.ndarray,
    reference: np.ndarray,
    grid: int,
    abs_floor: float,
    rel_floor: float,
    photometrics: Sequence[str],
    max_gain: float = 2.0,
) -> list[np.ndarray]:
    """Return :func:`cross_score` under each photometric model, sharing the statistics.

    Parameters
    ----------
    query, reference : numpy.ndarray
        Validated H x W x 3 images with the same aspect ratio (any resolutions).
    grid : int
        Cells per side.
    abs_floor, rel_floor : float
        Covariance regularisation (see :func:`regularised_precision`).
    photometrics : sequence of {"none", "cell_affine"}
        One score map is returned per entry, in order.
    max_gain : float
        Gain limit of the ``cell_affine`` fit.

    Returns
    -------
    list of numpy.ndarray
        H x W float32 raw scores, finite, each equal to the single-model result.
    """
    for photometric in photometrics:
        if photometric not in PHOTOMETRIC_MODELS:
            raise ValueError(f"photometric must be 'none' or 'cell_affine', got {photometric!r}")
    ref_stats = cell_statistics(reference, grid)
    query_stats = cell_statistics(query, grid)
    affine = None
    models = []
    for photometric in photometrics:
        if photometric == "none":
            models.append(_plain_models(ref_stats, query_stats, abs_floor, rel_floor))
            continue
        if affine is None:
            gain, offset = fit_cell_affine(query, reference, grid, max_gain)
            affine = (gain, offset, saturation_variance(reference, grid, max_gain))
        models.append(_affine_models(ref_stats, query_stats, *affine, abs_floor, rel_floor))
    return _evaluate(to_float32(query), grid, models, check_finite=abs_floor < _BOUNDED_FLOOR)


def _plain_models(
    ref_stats: CellStatistics, query_stats: CellStatistics, abs_floor: float, rel_floor: float
) -> CellModels:
    return CellModels(
        ref_mean=ref_stats.mean,
        ref_precision=regularised_precision(ref_stats.cov, abs_floor, rel_floor),
        query_mean=query_stats.mean,
        query_precision=regularised_precision(query_stats.cov, abs_floor, rel_floor),
    )


def _affine_models(
    ref_stats: CellStatistics,
    query_stats: CellStatistics,
    gain: np.ndarray,
    offset: np.ndarray,
    widening: np.ndarray,
    abs_floor: float,
    rel_floor: float,
) -> CellModels:
    # Score in the reference's photometric units (x_ref = (x - offset) / gain), so the
    # regularisation floors mean the same whatever the query's exposure: a darker query
    # does not hide its anomalies under a floor sized for the render. Both models are
    # widened where the reference is saturated, so identical images still cancel exactly.
    inverse = 1.0 / gain
    in_ref_units = query_stats.cov * inverse[:, :, None] * inverse[:, None, :]
    return CellModels(
        ref_mean=gain * ref_stats.mean + offset,
        ref_precision=_to_query_units(
            regularised_precision(ref_stats.cov + widening, abs_floor, rel_floor), inverse
        ),
        query_mean=query_stats.mean,
        query_precision=_to_query_units(
            regularised_precision(in_ref_units + widening, abs_floor, rel_floor), inverse
        ),
    )


def _to_query_units(precision: np.ndarray, inverse_gain: np.ndarray) -> np.ndarray:
    # A precision P on x_ref = (x - o) / g is D^-1 P D^-1 on x, D = diag(g).
    return precision * inverse_gain[:, :, None] * inverse_gain[:, None, :]


def rx_score(image: np.ndarray, abs_floor: float, rel_floor: float) -> np.ndarray:
    """Return the global RX score: squared Mahalanobis distance to the image's own model."""
    stats = cell_statistics(image, 1)
    precision = regularised_precision(stats.cov, abs_floor, rel_floor)
    model = CellModels(stats.mean, precision, stats.mean, np.zeros_like(precision))
    return _evaluate(to_float32(image), 1, [model], check_finite=abs_floor < _BOUNDED_FLOOR)[0]


def quadratic_coefficients(
    mu0: np.ndarray, p0: np.ndarray, mu1: np.ndarray, p1: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Coefficients of ``(x-mu0)^T p0 (x-mu0) - (x-mu1)^T p1 (x-mu1)`` around ``mu1``.

    Works on one cell (``mu`` of shape (3,), ``p`` of shape (3, 3)) or on a stack of cells
    (leading dimensions broadcast).

    Returns
    -------
    transform : numpy.ndarray
        (..., 3, 4) affine map ``x -> y = V^T (x - mu1)``.
    eigenvalues : numpy.ndarray
        (..., 3) eigenvalues ``l`` of ``A = p0 - p1``.
    linear : numpy.ndarray
        (..., 3) coefficients ``m`` of ``y``.
    constant : numpy.ndarray
        (...) ``k``, the score at ``x = mu1``.
    """
    a = p0 - p1
    a = 0.5 * (a + np.swapaxes(a, -1, -2))
    eigenvalues, vectors = np.linalg.eigh(a)
    vectors_t = np.swapaxes(vectors, -1, -2)
    delta = (mu1 - mu0)[..., :, None]
    p0_delta = p0 @ delta
    linear = (vectors_t @ (2.0 * p0_delta))[..., 0]
    constant = (np.swapaxes(delta, -1, -2) @ p0_delta)[..., 0, 0]
    transform = np.concatenate([vectors_t, -(vectors_t @ mu1[..., :, None])], axis=-1)
    return transform, eigenvalues, linear, constant


def _evaluate(
    image: np.ndarray, grid: int, models: Sequence[CellModels], check_finite: bool = True
) -> list[np.ndarray]:
    # Per cell and model the score is sum_i y_i (l_i y_i + m_i) + k: two 3 x 4 colour
    # transforms of the pixel (y and l * y + m), their product, and a 1 x 4 transform that
    # sums the channels and adds k straight into the score map. OpenCV vectorises only
    # 3- and 1-channel outputs, so each step keeps to those.
    height, width = image.shape[:2]
    prepared = []
    for model in models:
        transform, eigenvalues, linear, constant = quadratic_coefficients(
            model.ref_mean, model.ref_precision, model.query_mean, model.query_precision
        )
        weighted = eigenvalues[:, :, None] * transform
        weighted[:, :, 3] += linear
        channel_sum = np.ones((len(constant), 1, 4))
        channel_sum[:, 0, 3] = constant
        # A cell whose two models are identical scores its constant: no per-pixel work.
        trivial = ~(eigenvalues.any(axis=-1) | linear.any(axis=-1))
        prepared.append(
            (
                transform.astype(np.float32),
                weighted.astype(np.float32),
                channel_sum.astype(np.float32),
                constant,
                trivial,
            )
        )
    scores = [np.empty((height, width), dtype=np.float32) for _ in models]
    slices = cell_slices(height, width, grid)

    def evaluate_cells(indices: range) -> None:
        for index in indices:
            cell = slices[index]
            pixels = image[cell]
            for score, (transform, weighted, channel_sum, constant, trivial) in zip(
                scores, prepared, strict=True
            ):
                if trivial[index]:
                    score[cell] = constant[index]
                    continue
                products = cv2.multiply(
                    cv2.transform(pixels, transform[index]), cv2.transform(pixels, weighted[index])
                )
                cv2.transform(products, channel_sum[index], dst=score[cell])

    for_each_block(evaluate_cells, len(slices), pixels=height * width)
    for score in scores:
        if check_finite and not cv2.checkRange(score):
            # Only reachable with unregularised, near-singular statistics: saturate, never NaN.
            big = float(np.finfo(np.float32).max)
            np.nan_to_num(score, copy=False, nan=0.0, posinf=big, neginf=-big)
    return scores
