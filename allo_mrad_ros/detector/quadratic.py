"""Stage 1b's algebra: the per-cell quadratic form of the cross score, and its NumPy/OpenCV
evaluation over the pixels.

Per cell, ``(x-mu0)^T P0 (x-mu0) - (x-mu1)^T P1 (x-mu1)`` is one quadratic form in ``x``.
It is evaluated around the query mean in the eigenbasis of ``A = P0 - P1``:
``sum_i l_i y_i^2 + m . y + k`` with ``y = V^T (x - mu1)``. The coefficients are computed
in float64 (so equal statistics cancel exactly to ``A = 0``), the per-pixel evaluation in
float32, by every array backend (:mod:`.backends`) from the same :class:`PixelQuadratic`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from allo_mrad_ros.detector.grid import cell_slices
from allo_mrad_ros.detector.images import to_float32
from allo_mrad_ros.detector.threads import for_each_block


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


@dataclass(frozen=True)
class PixelQuadratic:
    """One model's per-cell coefficients, ready for the per-pixel evaluation.

    The score of pixel ``x`` (``xh = [x, 1]``) in cell ``c`` is
    ``sum((transform[c] @ xh) * (weighted[c] @ xh)) + constant[c]``.

    Attributes
    ----------
    transform : numpy.ndarray
        (G*G, 3, 4) float32: ``y = V^T (x - mu1)``.
    weighted : numpy.ndarray
        (G*G, 3, 4) float32: ``l * y + m``.
    constant : numpy.ndarray
        (G*G,) float64 ``k``; the evaluation adds it in float32.
    trivial : numpy.ndarray
        (G*G,) bool: the two models of the cell are identical, every pixel scores ``k``.
    """

    transform: np.ndarray
    weighted: np.ndarray
    constant: np.ndarray
    trivial: np.ndarray


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


def pixel_quadratic(model: CellModels) -> PixelQuadratic:
    """The per-pixel coefficients of one :class:`CellModels`."""
    transform, eigenvalues, linear, constant = quadratic_coefficients(
        model.ref_mean, model.ref_precision, model.query_mean, model.query_precision
    )
    weighted = eigenvalues[:, :, None] * transform
    weighted[:, :, 3] += linear
    # A cell whose two models are identical scores its constant: no per-pixel work.
    trivial = ~(eigenvalues.any(axis=-1) | linear.any(axis=-1))
    return PixelQuadratic(
        transform.astype(np.float32), weighted.astype(np.float32), constant, trivial
    )


def saturate_non_finite(score: np.ndarray) -> None:
    """Replace NaN by 0 and infinities by float32's extremes, in place (when any)."""
    if not cv2.checkRange(score):
        # Only reachable with unregularised, near-singular statistics: saturate, never NaN.
        big = float(np.finfo(np.float32).max)
        np.nan_to_num(score, copy=False, nan=0.0, posinf=big, neginf=-big)


def evaluate_quadratics(
    image: np.ndarray, grid: int, quadratics: Sequence[PixelQuadratic], check_finite: bool
) -> list[np.ndarray]:
    """Evaluate each model's quadratic form at every pixel, with OpenCV.

    Parameters
    ----------
    image : numpy.ndarray
        H x W x 3 validated image (uint8, uint16, or float on the 0..1 scale), evaluated
        as float32 on the 0..255 scale.
    grid : int
        Cells per side.
    quadratics : sequence of PixelQuadratic
        One per score map.
    check_finite : bool
        Saturate non-finite scores (only unregularised statistics can produce them).

    Returns
    -------
    list of numpy.ndarray
        H x W float32 score maps, in the order of ``quadratics``.
    """
    # Per cell the score is sum_i y_i (l_i y_i + m_i) + k: two 3 x 4 colour transforms of
    # the pixel (y and l * y + m), their product, and a 1 x 4 transform that sums the
    # channels and adds k straight into the score map. OpenCV vectorises only 3- and
    # 1-channel outputs, so each step keeps to those.
    image = to_float32(image)
    height, width = image.shape[:2]
    channel_sums = []
    for quadratic in quadratics:
        channel_sum = np.ones((len(quadratic.constant), 1, 4), dtype=np.float32)
        channel_sum[:, 0, 3] = quadratic.constant
        channel_sums.append(channel_sum)
    scores = [np.empty((height, width), dtype=np.float32) for _ in quadratics]
    slices = cell_slices(height, width, grid)

    def evaluate_cells(indices: range) -> None:
        for index in indices:
            cell = slices[index]
            pixels = image[cell]
            for score, quadratic, channel_sum in zip(scores, quadratics, channel_sums, strict=True):
                if quadratic.trivial[index]:
                    score[cell] = quadratic.constant[index]
                    continue
                products = cv2.multiply(
                    cv2.transform(pixels, quadratic.transform[index]),
                    cv2.transform(pixels, quadratic.weighted[index]),
                )
                cv2.transform(products, channel_sum[index], dst=score[cell])

    for_each_block(evaluate_cells, len(slices), pixels=height * width)
    if check_finite:
        for score in scores:
            saturate_non_finite(score)
    return scores
